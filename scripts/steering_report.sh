#!/usr/bin/env bash
# Publish the finished runs of a steering sweep into docs and rebuild their tables and plots:
#   bash scripts/steering_report.sh runs/arm2 docs/steering/arm2 16000
# Copies every run that reached STEPS env steps (the sweep's --steps) (log.csv, train.csv, run.json, summary.json; not the
# checkpoints) from SWEEP/{rust,sb3}/<task>/<method>/seed<S> to DOCS/runs/..., the base policy's
# success (<task>/base.json, measured once) beside them, then writes DOCS/table.md, DOCS/<task>.png
# (`python -m equigym.steer report`) and DOCS/diagnostics.md (`python -m equigym.steer diagnose`
# of every copied run: evaluations beside the learner's state).
set -euo pipefail
cd "$(dirname "$0")/.."
SWEEP=${1:?sweep output folder, e.g. runs/arm2}
DOCS=${2:?docs folder, e.g. docs/steering/arm2}
STEPS=${3:?env steps a finished run has reached, the --steps of the sweep}
PY=.venv/bin/python
rm -rf "$DOCS/runs"
copied=()
for agent in rust sb3; do
  for run in "$SWEEP/$agent"/*/*/seed*; do
    [ -f "$run/log.csv" ] || continue
    last=$(tail -n 1 "$run/log.csv" | cut -d, -f1)
    [ "$last" -ge "$STEPS" ] || continue  # still running: left out
    dest="$DOCS/runs/$agent/${run#"$SWEEP/$agent/"}"
    mkdir -p "$dest"
    for f in log.csv train.csv run.json summary.json; do
      [ -f "$run/$f" ] && cp "$run/$f" "$dest/"
    done
    # run.json names the policy file; keep it relative to the repository
    sed -i "s#\"$(pwd)/#\"#" "$dest/run.json"
    copied+=("$dest")
  done
done
# The base policy's success per task (100 episodes, latent noise N(0, I)), measured once into
# SWEEP/rust/<task>/base.json (which outlives republishing) and copied beside the runs.
for dir in "$DOCS/runs/rust"/*/; do
  task=$(basename "$dir")
  PYTHONPATH=. $PY -c "from baselines.steer import base_success; base_success('$task', '$SWEEP/rust', 100)"
  for agent in rust sb3; do
    if [ -d "$DOCS/runs/$agent/$task" ]; then cp "$SWEEP/rust/$task/base.json" "$DOCS/runs/$agent/$task/"; fi
  done
done
$PY -m equigym.steer report --runs "$DOCS/runs/rust" --sb3-runs "$DOCS/runs/sb3" --out "$DOCS" > /dev/null
$PY -m equigym.steer diagnose "${copied[@]}" --out "$DOCS/diagnostics.md" > /dev/null
echo "published ${#copied[@]} runs to $DOCS (table.md, diagnostics.md, plots)"
