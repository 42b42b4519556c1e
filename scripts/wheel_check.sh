#!/usr/bin/env bash
# Build the wheel, install it in a fresh virtual environment (no checkout on sys.path, run from
# a temporary directory) and check that every gymnasium id works, that the shipped files come
# from the installed package, and that the heavy extras are optional.
#
#   bash scripts/wheel_check.sh            # builds with maturin (release)
#   WHEEL=path/to.whl bash scripts/wheel_check.sh
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$(pwd)
PYTHON=${PYTHON:-python3}
WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT

if [ -z "${WHEEL:-}" ]; then
    MATURIN=${MATURIN:-$(command -v maturin || echo .venv/bin/maturin)}
    "$MATURIN" build --release --quiet --out "$WORK/dist"
    WHEEL=$(ls "$WORK"/dist/equigym-*.whl)
fi
echo "wheel: $WHEEL ($(du -h "$WHEEL" | cut -f1))"
# The wheel carries the URDF and the policies, not the training logs and plots.
"$PYTHON" - "$WHEEL" <<'PY'
import sys, zipfile
names = zipfile.ZipFile(sys.argv[1]).namelist()
need = ["equigym/shipped/panda/panda.urdf"] + [f"equigym/shipped/edp/{t}.safetensors" for t in ("lift", "stack", "square")]
missing = [n for n in need if n not in names]
extra = [n for n in names if n.endswith((".csv", ".png", ".ckpt"))]
assert not missing, f"missing from the wheel: {missing}"
assert not extra, f"should not be in the wheel: {extra}"
PY

"$PYTHON" -m venv "$WORK/venv"
"$WORK/venv/bin/python" -m pip install -q --upgrade pip
"$WORK/venv/bin/python" -m pip install -q "$WHEEL"

cd "$WORK"
"$WORK/venv/bin/python" - "$ROOT" <<'PY'
import sys
from pathlib import Path

import gymnasium
import numpy as np

import equigym

root = Path(sys.argv[1]).resolve()
package = Path(equigym.__file__).resolve()
assert root not in package.parents, f"equigym imported from the checkout: {package}"
assert root not in equigym.urdf_path().resolve().parents, "URDF found in the checkout"
ids = list(equigym.ENV_IDS) + list(equigym.LATENT_ENV_IDS)
for env_id in ids:
    env = gymnasium.make(env_id)
    obs, info = env.reset(seed=0)
    env.action_space.seed(0)
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    assert np.all(np.isfinite(obs)), env_id
    env.close()
print(f"gymnasium.make works on {len(ids)} ids from {package.parent}")
# Heavy dependencies stay optional: a clear message names the extra to install.
for module in ("torch", "stable_baselines3", "escnn", "ray"):
    try:
        __import__(module)
        raise SystemExit(f"{module} is installed by the core wheel; it should be an extra")
    except ImportError:
        pass
try:
    import equigym.replay  # noqa: F401
except ImportError as exc:
    assert "pip install 'equigym[train]'" in str(exc), exc
else:
    raise SystemExit("equigym.replay imported without torch")
print("optional extras: clear message when missing")
PY

# The steering report runs from the installed package (it imports nothing from the checkout's
# baselines/) on a committed run directory; without the plot extra it writes the tables only.
"$WORK/venv/bin/python" -m equigym.steer report --runs "$ROOT/docs/steering/arm4/stack-recipe" --out "$WORK/report" >/dev/null
grep -q "DSRL (Rust)" "$WORK/report/table.md"
echo "equigym.steer report: works from the wheel"
