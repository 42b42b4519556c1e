#!/usr/bin/env bash
# Profile the single-environment control step with perf (one core, uniform random actions).
#   bash benches/profile.sh [task] [steps]      # writes benches/results/profile_<task>.txt
# Needs `perf` (linux-tools); the release profile keeps debug info (Cargo.toml: debug = 1).
set -euo pipefail
cd "$(dirname "$0")/.."
TASK=${1:-lift}
STEPS=${2:-3000}
OUT=benches/results/profile_$TASK.txt
DATA=$(mktemp /tmp/equigym-perf.XXXXXX)
trap 'rm -f "$DATA"' EXIT
cargo build --release -q -p equigym-envs --example throughput
perf record -q -g --call-graph dwarf -F 2000 -o "$DATA" -- taskset -c 0 target/release/examples/throughput "$TASK" "$STEPS" >/dev/null
set +o pipefail  # head closes the pipes early
{
  echo "# perf profile of target/release/examples/throughput $TASK $STEPS (pinned to CPU 0)"
  echo "# $(date -Iseconds), load average: $(cut -d' ' -f1-3 /proc/loadavg), git $(git rev-parse --short HEAD)"
  echo
  echo "## Inclusive time (children included) of the main stages"
  perf report -i "$DATA" --children --sort symbol --stdio 2>/dev/null | grep -E '^ +[0-9]' \
    | grep -E 'Env::step|control_step|PhysicsPipeline::step |step_inner|build_islands_and_solve|init_and_solve|run_worker|solve_ik|jacobian|CCDSolver::solve_continuous|compute_contacts|BroadPhaseBvh>::update|evaluate|observe' \
    | grep -v 0xffffffff | sed -E 's/ +- +- +$//; s/ {2,}/  /g' | head -30
  echo
  echo "## Self time, top 30 symbols"
  perf report -i "$DATA" --no-children --sort symbol --stdio 2>/dev/null | grep -E '^ +[0-9]' \
    | grep -v 0xffffffff | sed -E 's/ +- +- +$//; s/ {2,}/  /g' | head -30
} > "$OUT"
echo "wrote $OUT"
