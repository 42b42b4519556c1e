#!/usr/bin/env bash
# The main job: steer the shipped Lift EDP with Equi-DSRL (the Rust agents, bit-reproducible)
# for a few minutes and print what steering did (before/after table,
# runs/headline/report/lift.png); first a short scripted-expert rollout of the same task
# (success rate, steps/s, runs/demo/*.png and *.gif).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
.venv/bin/python -m equigym.demo --env EquiLift-v0 --episodes 20 --out runs/demo
.venv/bin/python -m baselines.headline "$@"
