#!/usr/bin/env bash
# The Stack D1 base-policy screen (docs/edp.md, "Stack D1"): the same trainer (C8 EDP, 64
# regular fields, 40k steps) on clean demos (100, two seeds; 300), on 100 demos with one step of
# observation history, and on 100 DART demos (execution noise 5 mm, four seeds; 10 mm); each policy
# evaluated on the 200 pinned starts (`baselines.edp eval`) and broken down by how it loses the
# cube (`baselines.edp failures`). Resumable: demos, trained weights and result files that
# exist are kept. About 15 minutes per policy on one core of this 2-core machine. Each policy is
# also run on 200 validation starts (`failures --validation`): the one to ship is chosen there.
# Usage: bash scripts/stack_edp_screen.sh [OUT] [NAME ...]
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-docs/edp/stack-screen}
shift || true
PY=.venv/bin/python
RUNS=runs/edp/stack-screen
mkdir -p "$OUT" "$RUNS" data
demos() { # name episodes [execution noise]
    [ -f "data/$1.hdf5" ] || $PY -m equigym.demos --task stack --variant D1 --episodes "$2" \
        --execution-noise "${3:-0}" --out "data/$1.hdf5"
}
demos stack_d1_100 100
demos stack_d1_300 300
demos stack_d1_100_dart005 100 0.005
demos stack_d1_100_dart01 100 0.01
keep() { # file command...: write the command's output to file only when it finishes
    local file=$1
    shift
    "$@" >"$file.part" && mv "$file.part" "$file"
}
# name: demo file, extra training arguments
declare -A CONFIGS=(
    [clean]="stack_d1_100"
    [clean_seed1]="stack_d1_100 --seed 1"
    [clean_history2]="stack_d1_100 --obs-history 2"
    [clean_300]="stack_d1_300"
    [dart005]="stack_d1_100_dart005"
    [dart005_seed1]="stack_d1_100_dart005 --seed 1"
    [dart005_seed2]="stack_d1_100_dart005 --seed 2"
    [dart005_seed3]="stack_d1_100_dart005 --seed 3"
    [dart01]="stack_d1_100_dart01"
)
NAMES=("$@")
[ ${#NAMES[@]} -gt 0 ] || NAMES=(clean clean_seed1 clean_history2 clean_300 dart005 dart005_seed1 dart005_seed2 dart005_seed3 dart01)
for name in "${NAMES[@]}"; do
    read -r data extra <<<"${CONFIGS[$name]}"
    policy="$RUNS/$name.safetensors"
    # shellcheck disable=SC2086
    [ -f "$policy" ] || $PY -m baselines.edp train --demos "data/$data.hdf5" --out "$policy" \
        --steps 40000 --hidden-fields 64 $extra
    # History policies need the conditioning that only `failures` builds; the rest run both.
    if ! grep -q -- "--obs-history 2" <<<"$extra"; then
        [ -s "$OUT/$name.eval.json" ] || keep "$OUT/$name.eval.json" $PY -m baselines.edp eval --policy "$policy"
    fi
    [ -s "$OUT/$name.failures.json" ] || keep "$OUT/$name.failures.json" \
        $PY -m baselines.edp failures --policy "$policy" --episodes 200
    # Model choice is made on the validation starts, never on the evaluation starts.
    [ -s "$OUT/$name.validation.json" ] || keep "$OUT/$name.validation.json" \
        $PY -m baselines.edp failures --policy "$policy" --episodes 200 --validation
done
$PY - "$OUT" <<'PYEOF'
import json, pathlib, sys
out = pathlib.Path(sys.argv[1])
print("| policy | validation (200 starts) | eval (200 pinned starts) | failures' own draws | never lifted | opened | slipped | held at horizon | successes after a drop |")
print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
for f in sorted(out.glob("*.failures.json")):
    name = f.name.removesuffix(".failures.json")
    fl = json.loads(f.read_text())
    e = out / f"{name}.eval.json"
    ev = json.loads(e.read_text()) if e.exists() else None
    v = out / f"{name}.validation.json"
    val = json.loads(v.read_text()) if v.exists() else None
    rate = lambda r: f"{r['success_rate']:.3f} [{r['low']:.3f}, {r['high']:.3f}]"
    c = fl["counts"]
    print(f"| {name} | {rate(val) if val else '-'} | {rate(ev) if ev else '-'} | {rate(fl)} | {c.get('never lifted', 0)} | "
          f"{c.get('opened away', 0) + c.get('opened over target', 0)} | {c.get('slipped', 0)} | "
          f"{c.get('held at horizon', 0)} | {fl['successes_after_a_drop']} |")
PYEOF
