#!/usr/bin/env bash
# The main job: steer the shipped Lift EDP with the Rust agents (DSRL-NA recipe, bit-reproducible)
# for a few minutes and print what steering did beside its controls on the same pinned starts
# (runs/headline/report/compare.md, lift.png); first a short scripted-expert rollout of the same
# task (success rate, steps/s, runs/demo/*.png and *.gif).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
.venv/bin/python -m equigym.demo --env EquiLift-v0 --episodes 20 --out runs/demo
.venv/bin/python -m baselines.headline "$@"
