#!/usr/bin/env bash
# The Lift EDP's training budget and demo length against its base success and steerability
# (docs/steering.md, "Steerability"): 3 demos as in the paper, trained for 4k (the shipped
# EDP's budget), 8k and 16k steps, and demos that go on 12 / 60 expert steps after success;
# the steerability diagnostic's base rollouts for each, its probes for the 8k and 16k EDPs.
# About 20 minutes on 2 cores. Usage: bash scripts/lift_edp_training.sh [OUT]
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-docs/steering/steerability/lift-edp-training}
PY=.venv/bin/python
mkdir -p "$OUT/edp" data
$PY -m equigym.demos --task lift --episodes 3 --out data/lift_3.hdf5
for hold in 12 60; do
    $PY -m equigym.demos --task lift --episodes 3 --hold-steps $hold --out data/lift_3_hold$hold.hdf5
done
train() { $PY -m baselines.edp train --demos "$1" --out "$OUT/edp/$2.safetensors" --steps "$3" --fresh; }
train data/lift_3.hdf5 plain_4k 4000
train data/lift_3.hdf5 plain_8k 8000
train data/lift_3.hdf5 plain_16k 16000
train data/lift_3_hold12.hdf5 hold12_4k 4000
train data/lift_3_hold12.hdf5 hold12_8k 8000
train data/lift_3_hold60.hdf5 hold60_4k 4000
cargo build --release -p equigym-wrappers --example steerability
for name in plain_4k plain_8k plain_16k hold12_4k hold12_8k hold60_4k; do
    parts=base
    case $name in plain_8k | plain_16k) parts=base,probe ;; esac
    ./target/release/examples/steerability --task lift --policy "$OUT/edp/$name.safetensors" --parts $parts \
        --out "$OUT/$name"
done
