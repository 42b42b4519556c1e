#!/usr/bin/env bash
# The vector env's thread scaling, this build against an earlier one: the pure-Rust batch
# (examples/vector_throughput, uniform random actions, auto-reset) of both builds, runs
# alternating between the builds, each run timing T = 1 and T = 2 back to back for every B;
# the scaling of a round is its T=2 rate over its T=1 rate, and the table gives the median over
# the rounds (the machine's speed drifts between runs by more than the differences looked for).
#   bash benches/ab_vector.sh REV [batch steps] [rounds]     # writes benches/results/ab_vector_<REV>.md
# REV is built in a temporary worktree with its own target directory (cached under
# ~/.cache/equigym-ab/<commit>, as benches/ab_build.sh does).
set -euo pipefail
cd "$(dirname "$0")/.."
REV=${1:?usage: bash benches/ab_vector.sh REV [batch steps] [rounds]}
STEPS=${2:-150}
ROUNDS=${3:-5}
SIZES=16,32,64
COMMIT=$(git rev-parse --short "$REV")
source benches/ab_common.sh
OLD=$(ab_example "$COMMIT" vector_throughput)
cargo build --release -q -p equigym-envs --example vector_throughput
NEW=target/release/examples/vector_throughput
HEAD_DESC="$(git rev-parse --short HEAD)$(git diff --quiet HEAD -- . ':!benches/results' || echo '+changes')"
OUT=benches/results/ab_vector_${COMMIT}.md
LOG=$(mktemp)
for r in $(seq "$ROUNDS"); do
  for build in old new; do
    bin=$OLD; [[ $build == new ]] && bin=$NEW
    taskset -c 0,1 "$bin" lift "$STEPS" "$SIZES" 1,2 | sed -E "s/^/$build $r /" >>"$LOG"
  done
done
{
  echo "# Vector env thread scaling, this build against $COMMIT"
  echo
  echo "\`bash benches/ab_vector.sh $REV $STEPS $ROUNDS\`: $(date -Iseconds), $(lscpu | sed -nE 's/^Model name: +//p'),"
  echo "$(nproc) CPUs; Lift, $STEPS batch steps per (B, T), $ROUNDS rounds alternating between the builds."
  echo "This build: $HEAD_DESC. Load average after: $(cut -d' ' -f1-3 /proc/loadavg)."
  echo
  python3 - "$LOG" "$COMMIT" <<'PY'
import re, statistics, sys
rates = {}
for line in open(sys.argv[1]):
    m = re.match(r"(\w+) (\d+) B=(\d+) T=(\d+): (\d+) env steps/s", line)
    if m:
        build, r, b, t, rate = m.group(1), int(m.group(2)), int(m.group(3)), int(m.group(4)), int(m.group(5))
        rates[(build, r, b, t)] = rate
print(f"| B | {sys.argv[2]}: 2 threads / 1, median (rounds) | this build: 2 threads / 1, median (rounds) |")
print("|---:|---|---|")
for b in sorted({k[2] for k in rates}):
    cells = []
    for build in ("old", "new"):
        xs = [rates[(build, r, b, 2)] / rates[(build, r, b, 1)] for (bb, r, b2, t) in rates
              if bb == build and b2 == b and t == 1 and (build, r, b, 2) in rates]
        cells.append(f"**{statistics.median(xs):.2f}x** ({', '.join(f'{x:.2f}' for x in xs)})" if xs else "-")
    print(f"| {b} | " + " | ".join(cells) + " |")
PY
} | tee "$OUT"
rm -f "$LOG"
echo "wrote $OUT"
