#!/usr/bin/env bash
# Create .venv, install the Python dependencies and build the Rust extension into it.
# Idempotent: a second run only rebuilds what changed.
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
    "$PYTHON" -m venv .venv
fi
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q "maturin>=1.5,<2"
# --extras installs the package's own dependencies plus the test tools, and Ray Tune (sweep) so
# that the sweep's test runs too.
.venv/bin/maturin develop --release --quiet --extras test,train,bench,lint,sweep
# escnn without its optional Fortran-built dependency (py3nj); lie_learn is imported by escnn.
.venv/bin/python -m pip install -q --no-deps "escnn==1.0.11" "lie_learn==0.0.2"
