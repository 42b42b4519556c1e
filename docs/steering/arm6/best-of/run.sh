#!/usr/bin/env bash
# The Stack D1 h20 learner at 60k env steps used four ways on 400 pinned evaluation starts
# (docs/steering.md, "Does the critic know which noise succeeds?"). ~7 min on 2 cores.
# One JSON line per arm: docs/steering/arm6/best-of/stack-h20-400.jsonl. An out directory
# with no checkpoint (/tmp/untrained) gives the untrained learner: its best-of-N is the base
# policy on the same candidate noises (common random numbers).
set -euo pipefail
cd "$(dirname "$0")/../../../.."
C="--method dsrl --task stack --seed 0 --steps 60000 --eval-every 20000 --eval-episodes 100 --terminate-on-success --target-entropy 20 --threads 2 --episodes 400"
for n in 16 64; do
  target/release/steer eval $C --out /tmp/untrained --actor best-of-$n
  target/release/steer eval $C --out docs/steering/arm6/stack-h20 --actor best-of-$n
done
target/release/steer eval $C --out docs/steering/arm6/stack-h20 --actor sampled
target/release/steer eval $C --out docs/steering/arm6/stack-h20 --actor mean
target/release/steer eval $C --out /tmp/untrained --actor mean   # control: the untrained actor's mean
# The KL-budget runs (4 and 10 nats) the same ways: docs/steering/arm6/best-of/stack-kl-400.jsonl (~12 min).
for k in 4 10; do
  K="--method dsrl --task stack --seed 0 --steps 60000 --eval-every 20000 --eval-episodes 100 --terminate-on-success --prior-kl $k --threads 2 --episodes 400 --out docs/steering/arm6/stack-kl$k"
  for a in mean sampled best-of-16; do target/release/steer eval $K --actor $a >&2; done
done
