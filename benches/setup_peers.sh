#!/usr/bin/env bash
# Create the robosuite virtualenv that benches/peers.py compares against.
# Idempotent: does nothing if the venv already imports robosuite + mujoco at the pinned versions.
#   bash benches/setup_peers.sh            # ~3 min, ~1 GB
#   EQUIGYM_PEERS_DIR=/somewhere bash benches/setup_peers.sh
set -euo pipefail

DIR=${EQUIGYM_PEERS_DIR:-$HOME/.cache/equigym-peers}
VENV=$DIR/venv_robosuite
PY=${PYTHON:-python3}
# robosuite 1.5.2 breaks on mujoco >= 3.10 (controller asserts / mj_fullM signature); 3.9.0 is the newest that works.
ROBOSUITE=1.5.2
MUJOCO=3.9.0

check() {
  [ -x "$VENV/bin/python" ] && MUJOCO_GL=egl "$VENV/bin/python" - <<EOF 2>/dev/null
import robosuite, mujoco
assert robosuite.__version__ == "$ROBOSUITE" and mujoco.__version__ == "$MUJOCO"
EOF
}

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
