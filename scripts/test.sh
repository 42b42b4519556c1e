#!/usr/bin/env bash
# All tests: Rust (cargo test) and Python (pytest), after the same set-up as the main job.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
cargo test --workspace --exclude equigym-python
.venv/bin/python -m pytest -q tests "$@"
