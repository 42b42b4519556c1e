#!/usr/bin/env bash
# This build against an earlier one, side by side: both compiled, runs alternating on one core,
# best of N per task (control steps/s of examples/throughput under the same random actions), and
# whether the two builds end the run in the same state (the saved state's checksum; only builds
# that both print it can be compared).
#   bash benches/ab_build.sh REV [steps] [rounds]     # writes benches/results/ab_<REV>.md
# REV is any git revision; it is built in a temporary worktree with its own target directory
# (cached under ~/.cache/equigym-ab/<commit>, so a second run does not rebuild it).
set -euo pipefail
cd "$(dirname "$0")/.."
REV=${1:?usage: bash benches/ab_build.sh REV [steps] [rounds]}
STEPS=${2:-3000}
ROUNDS=${3:-3}
CPU=${CPU:-0}
COMMIT=$(git rev-parse --short "$REV")
source benches/ab_common.sh
OLD=$(ab_example "$COMMIT" throughput)
cargo build --release -q -p equigym-envs --example throughput
NEW=target/release/examples/throughput
HEAD_DESC="$(git rev-parse --short HEAD)$(git diff --quiet HEAD -- . ':!benches/results' || echo '+changes')"
OUT=benches/results/ab_${COMMIT}.md

rate() { sed -E 's/.*: ([0-9]+) control steps\/s.*/\1/'; }
checksum() { sed -nE 's/.*final state checksum ([0-9a-f]+).*/\1/p'; }
{
  echo "# This build against $COMMIT"
  echo
  echo "\`bash benches/ab_build.sh $REV $STEPS $ROUNDS\`: $(date -Iseconds), $(lscpu | sed -nE 's/^Model name: +//p'),"
  echo "one core (CPU $CPU), $STEPS control steps of uniform random actions per run, runs alternating, best of $ROUNDS."
  echo "This build: $HEAD_DESC. Load average before: $(cut -d' ' -f1-3 /proc/loadavg)."
  echo
  echo "| task | $COMMIT (steps/s) | this build (steps/s) | speed-up | same final state |"
  echo "|---|---|---|---|---|"
  for task in lift stack square; do
    best_old=0; best_new=0; sum_old=""; sum_new=""
    for _ in $(seq "$ROUNDS"); do
      o=$(taskset -c "$CPU" "$OLD" "$task" "$STEPS"); n=$(taskset -c "$CPU" "$NEW" "$task" "$STEPS")
      ro=$(echo "$o" | rate); rn=$(echo "$n" | rate)
      (( ro > best_old )) && best_old=$ro
      (( rn > best_new )) && best_new=$rn
      sum_old=$(echo "$o" | checksum); sum_new=$(echo "$n" | checksum)
    done
    same="-"
    [[ -n $sum_old && -n $sum_new ]] && { [[ $sum_old == "$sum_new" ]] && same=yes || same=no; }
    echo "| $task | $best_old | $best_new | $(python3 -c "print(f'{$best_new / $best_old:.2f}x')") | $same |"
  done
  echo
  echo "Load average after: $(cut -d' ' -f1-3 /proc/loadavg)."
} | tee "$OUT"
echo "wrote $OUT"
