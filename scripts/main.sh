#!/usr/bin/env bash
# The main job: scripted-expert rollouts on Lift (success rate, throughput, a PNG and a GIF).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
.venv/bin/python -m equigym.demo --env EquiLift-v0 --episodes 50 --out runs/demo "$@"
