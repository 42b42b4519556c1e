#!/usr/bin/env bash
# Create the peer virtualenvs that benches/peers.py and benches/suite.py compare against:
# robosuite (venv_robosuite) and panda-gym (venv_pandagym).
# Idempotent: does nothing for a venv that already imports its simulator at the pinned versions.
#   bash benches/setup_peers.sh            # ~3 min, ~1 GB
#   EQUIGYM_PEERS_DIR=/somewhere bash benches/setup_peers.sh
set -euo pipefail

DIR=${EQUIGYM_PEERS_DIR:-$HOME/.cache/equigym-peers}
VENV=$DIR/venv_robosuite
PG_VENV=$DIR/venv_pandagym
PY=${PYTHON:-python3}
# robosuite 1.5.2 breaks on mujoco >= 3.10 (controller asserts / mj_fullM signature); 3.9.0 is the newest that works.
ROBOSUITE=1.5.2
MUJOCO=3.9.0
PANDA_GYM=3.0.7

pandagym() {
  pg_check() {
    [ -x "$PG_VENV/bin/python" ] && "$PG_VENV/bin/python" -c "import panda_gym; from importlib.metadata import version; assert version('panda-gym') == '$PANDA_GYM'" 2>/dev/null
  }
  if pg_check; then
    echo "panda-gym venv OK: $PG_VENV"
    return 0
  fi
  mkdir -p "$DIR"
  "$PY" -m venv --clear "$PG_VENV"
  "$PG_VENV/bin/pip" install -q --upgrade pip
  "$PG_VENV/bin/pip" install -q "panda-gym==$PANDA_GYM"
  pg_check && echo "panda-gym venv ready: $PG_VENV"
}

check() {
  [ -x "$VENV/bin/python" ] && MUJOCO_GL=egl "$VENV/bin/python" - <<EOF 2>/dev/null
import robosuite, mujoco
assert robosuite.__version__ == "$ROBOSUITE" and mujoco.__version__ == "$MUJOCO"
EOF
}

pandagym || echo "panda-gym venv at $PG_VENV could not be built (suite.py skips panda-gym)" >&2

if check; then
  echo "robosuite venv OK: $VENV"
  exit 0
fi

mkdir -p "$DIR"
# --clear so a half-built venv from an interrupted run is rebuilt rather than patched.
"$PY" -m venv --clear "$VENV"
"$VENV/bin/pip" install -q --upgrade pip
"$VENV/bin/pip" install -q "robosuite==$ROBOSUITE" "mujoco==$MUJOCO"

if check; then
  echo "robosuite venv ready: $VENV"
else
  echo "robosuite venv at $VENV does not import robosuite==$ROBOSUITE / mujoco==$MUJOCO" >&2
  exit 1
fi
