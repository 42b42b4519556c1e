#!/usr/bin/env bash
# Steering by selection on Stack D1 (docs/steering.md, "Selection instead of an actor"):
# the learners, then each used as the best of N fresh N(0, I) candidates on 400 pinned starts,
# and the critic probe of the base-policy critic. One JSON line per evaluation in
# docs/steering/arm7/select-400.jsonl. Cost on 2 cores: the runs 8 min (select 1) and 21 min
# (select 16) on one core each, side by side; the evaluations 1.5-3 min each; the probe 8 min.
set -euo pipefail
cd "$(dirname "$0")/../../.."
R="--method dsrl --task stack --seed 0 --steps 60000 --eval-every 20000 --eval-episodes 100 --terminate-on-success"
for rs in "" "--reward-scale 0.01"; do
  sfx=${rs:+-rs0.01}
  target/release/steer run $R --select 1 $rs --threads 1 --out docs/steering/arm7/stack-select1$sfx &
  target/release/steer run $R --select 16 $rs --threads 1 --out docs/steering/arm7/stack-select16$sfx
  wait
done
E="$R --threads 2 --episodes 400"
out=docs/steering/arm7/select-400.jsonl
: > $out
# The control: an untrained critic's pick among the same fresh candidates is the base policy.
target/release/steer eval $E --select 16 --out /tmp/untrained-sel --actor best-of-16 >> $out
for rs in "" "--reward-scale 0.01"; do
  sfx=${rs:+-rs0.01}
  target/release/steer eval $E --select 1 $rs --out docs/steering/arm7/stack-select1$sfx --actor best-of-16 >> $out
  for n in 16 64; do
    target/release/steer eval $E --select 16 $rs --out docs/steering/arm7/stack-select16$sfx --actor best-of-$n >> $out
  done
done
for rs in "" "--reward-scale 0.01"; do
  sfx=${rs:+-rs0.01}
  target/release/steer probe $R --select 1 $rs --threads 2 --out docs/steering/arm7/stack-select1$sfx \
    --report docs/steering/arm7/critic-probe/stack-select1$sfx
done
