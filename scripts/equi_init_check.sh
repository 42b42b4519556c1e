#!/usr/bin/env bash
# The untrained SB3 + escnn Equi-DSRL actor's success on Lift under escnn's initialisation and
# under PyTorch's default scale (--equi-init torch, the Rust agents' scale), beside the Rust
# agents' first evaluations: the first evaluation of a run (env step 16, 50 episodes) only,
# about a minute per seed. Runs that exist are kept (rerun to finish an interrupted check).
#   bash scripts/equi_init_check.sh runs/init docs/steering/arm3/init docs/steering/arm3/runs/rust/lift/equi
set -euo pipefail
cd "$(dirname "$0")/.."
RUNS=${1:?output folder for the runs, e.g. runs/init}
DOCS=${2:?docs folder, e.g. docs/steering/arm3/init}
RUST=${3:?the Rust Equi-DSRL runs to compare with, e.g. docs/steering/arm3/runs/rust/lift/equi}
PY=.venv/bin/python
for s in 0 1 2 3 4; do
  for init in escnn torch; do
    [ -f "$RUNS/$init/lift/equi/seed$s/log.csv" ] && continue
    PYTHONPATH=. $PY -m baselines.steer run --method equi --task lift --seed "$s" --steps 16 \
      --out "$RUNS/$init" --equi-init "$init" --no-progress > /dev/null
  done
done
mkdir -p "$DOCS"
for init in escnn torch; do
  for run in "$RUNS/$init"/lift/equi/seed*; do
    dest="$DOCS/$init/$(basename "$run")"
    mkdir -p "$dest"
    cp "$run/log.csv" "$run/run.json" "$dest/"
  done
done
PYTHONPATH=. $PY - "$DOCS" "$RUST" <<'PYEOF'
import csv, sys
from pathlib import Path
from equigym.steer.stats import format_mean_se

docs, rust = Path(sys.argv[1]), Path(sys.argv[2])


def first(run: Path) -> float:
    with open(run / "log.csv") as f:
        return float(next(csv.DictReader(f))["success_rate"])


rows = [
    ("SB3 + escnn, escnn's initialisation (default)", sorted((docs / "escnn").glob("seed*"))),
    ("SB3 + escnn, PyTorch's default scale (`--equi-init torch`)", sorted((docs / "torch").glob("seed*"))),
    ("Rust agents (their first evaluation in the sweep)", sorted(rust.glob("seed*"))),
]
lines = [
    "# Equi-DSRL on Lift before any training: success of the untrained actor",
    "",
    "From `bash scripts/equi_init_check.sh`: the first evaluation of each run (env step 16, 50 episodes,",
    "the stochastic actor; the base policy alone scores 0.540).",
    "",
    "| actor | seeds | success, mean +- s.e. | per seed |",
    "|---|---:|---:|---|",
]
for name, runs in rows:
    v = [first(r) for r in runs]
    lines.append(f"| {name} | {len(v)} | {format_mean_se(v, 3)} | {', '.join(f'{x:.2f}' for x in v)} |")
(docs / "table.md").write_text("\n".join(lines) + "\n")
print("\n".join(lines))
PYEOF
