#!/usr/bin/env bash
# Why Stack D1 falls as training starts (docs/steering.md, "Why Stack D1 falls as training
# starts"). The study's Equi-DSRL run of seed 0 (recipe na-tos-h20, 32k env steps, its
# checkpoint local to the machine that ran the study) is rerun to 8k env steps, where the fall
# is first seen; both checkpoints are then used as policies on 200 pinned starts (the actor's
# samples, its mean, the critic's best of 16 fresh N(0, I) candidates; an out directory with no
# checkpoint gives the untrained learner, whose best of 16 is the base on the same candidates),
# and the critic probe scores one chunk's noise against its Monte-Carlo success at both points.
# One JSON line per evaluation in evals.jsonl; probe reports under probe-8k/ and probe-32k/.
# Cost on 2 cores: about 35 min.
set -euo pipefail
cd "$(dirname "$0")/../../../.."
here=docs/steering/study/stack-collapse
R="--method equi --task stack --seed 0 --eval-every 4000 --terminate-on-success --noise-aliased --target-entropy 20 --policy assets/edp/stack.safetensors --edp-kernel dense"
study=docs/steering/study/runs/stack
test -f $study/stack/equi/seed0/checkpoint.bin || { echo "needs the study's Stack seed-0 Equi-DSRL checkpoint (python -m equigym.study run --parts table1)" >&2; exit 1; }
out=$here/evals.jsonl
untrained=$(mktemp -d)   # an out directory with no checkpoint: the untrained learner
# evals AT DIR THREADS ARM...: the learner in DIR (trained to AT env steps) as a policy, one
# JSON line per arm, labelled with AT and the arm.
evals() {
  local at=$1 dir=$2 threads=$3 a
  shift 3
  for a in "$@"; do
    target/release/steer eval $R --steps $((at > 0 ? at : 8000)) --threads $threads --episodes 200 --out $dir --actor $a |
      sed "s/^{/{\"at\":$at,\"arm\":\"$a\",/" >> $out
  done
}
: > $out
# 1. The run to 8k (its log must match the study run's first 8k), beside the 32k evaluations;
#    a failure of either stops both.
target/release/steer run $R --steps 8000 --threads 1 --quiet --out $here/at8k &
trap 'kill $! 2>/dev/null || true' ERR
evals 32000 $study 1 sampled mean best-of-16
wait $!
trap - ERR
# 2. The 8k learner the same ways, and the untrained controls (same starts, same candidates).
evals 8000 $here/at8k 2 sampled mean best-of-16
evals 0 "$untrained" 2 sampled best-of-16
# 3. The critic probe at both points.
target/release/steer probe $R --steps 8000 --threads 2 --out $here/at8k --report $here/probe-8k
target/release/steer probe $R --steps 32000 --threads 2 --out $study --report $here/probe-32k
