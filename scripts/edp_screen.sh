#!/usr/bin/env bash
# Base-policy screens (docs/edp.md, "Stack D1" and "Square D2"): the same trainer (C8 EDP, 64
# regular fields) on different demos, seeds and budgets; each policy evaluated on the 200 pinned
# starts (`baselines.edp eval`), broken down by how it loses the object (`baselines.edp
# failures`) and run on 200 validation starts (`failures --validation`): the one to ship is
# chosen there, never on the evaluation starts.
#   stack: clean demos (100, two seeds; 300), 100 demos with one step of observation history,
#          100 DART demos (execution noise 5 mm, four seeds; 10 mm); 40k steps.
#   square: 200 DART demos (5 mm) of the handle-grasping expert at 40k steps (two seeds; 128 fields) and 80k. (The
#          dart005* result files in docs/edp/square-screen/ are of the earlier ring-grasping
#          expert, commit 1a83fa5 and before; this script no longer makes its demos.)
# Resumable: demos, trained weights (and their training checkpoints) and result files that exist
# are kept. A 40k-step run takes about 15 minutes on one core of this 2-core machine.
# Usage: bash scripts/edp_screen.sh TASK [OUT] [NAME ...]
set -euo pipefail
cd "$(dirname "$0")/.."
TASK=${1:?usage: bash scripts/edp_screen.sh stack|square [OUT] [NAME ...]}
shift
OUT=${1:-docs/edp/$TASK-screen}
shift || true
PY=.venv/bin/python
RUNS=runs/edp/$TASK-screen
mkdir -p "$OUT" "$RUNS" data
demos() { # name variant episodes [execution noise]
    [ -f "data/$1.hdf5" ] || $PY -m equigym.demos --task "$TASK" --variant "$2" --episodes "$3" \
        --execution-noise "${4:-0}" --out "data/$1.hdf5"
}
keep() { # file command...: write the command's output to file only when it finishes
    local file=$1
    shift
    "$@" >"$file.part" && mv "$file.part" "$file"
}
# name: demo file, extra training arguments
declare -A CONFIGS
case $TASK in
stack)
    demos stack_d1_100 D1 100
    demos stack_d1_300 D1 300
    demos stack_d1_100_dart005 D1 100 0.005
    demos stack_d1_100_dart01 D1 100 0.01
    CONFIGS=(
        [clean]="stack_d1_100 --steps 40000"
        [clean_seed1]="stack_d1_100 --steps 40000 --seed 1"
        [clean_history2]="stack_d1_100 --steps 40000 --obs-history 2"
        [clean_300]="stack_d1_300 --steps 40000"
        [dart005]="stack_d1_100_dart005 --steps 40000"
        [dart005_seed1]="stack_d1_100_dart005 --steps 40000 --seed 1"
        [dart005_seed2]="stack_d1_100_dart005 --steps 40000 --seed 2"
        [dart005_seed3]="stack_d1_100_dart005 --steps 40000 --seed 3"
        [dart01]="stack_d1_100_dart01 --steps 40000"
    )
    ;;
square)
    demos square_d2_200_dart005_handle D2 200 0.005
    CONFIGS=(
        [handle_dart005]="square_d2_200_dart005_handle --steps 40000"
        [handle_dart005_seed1]="square_d2_200_dart005_handle --steps 40000 --seed 1"
        [handle_dart005_80k]="square_d2_200_dart005_handle --steps 80000"
        [handle_dart005_f128]="square_d2_200_dart005_handle --steps 40000 --hidden-fields 128"
    )
    ;;
*)
    echo "no screen for task '$TASK' (stack or square)" >&2
    exit 2
    ;;
esac
NAMES=("$@")
[ ${#NAMES[@]} -gt 0 ] || mapfile -t NAMES < <(printf '%s\n' "${!CONFIGS[@]}" | sort)
for name in "${NAMES[@]}"; do
    read -r data extra <<<"${CONFIGS[$name]}"
    policy="$RUNS/$name.safetensors"
    # shellcheck disable=SC2086
    [ -f "$policy" ] || $PY -m baselines.edp train --demos "data/$data.hdf5" --out "$policy" \
        --hidden-fields 64 $extra
    # History policies need the conditioning that only `failures` builds; the rest run both.
    if ! grep -q -- "--obs-history 2" <<<"$extra"; then
        [ -s "$OUT/$name.eval.json" ] || keep "$OUT/$name.eval.json" $PY -m baselines.edp eval --policy "$policy"
    fi
    [ -s "$OUT/$name.failures.json" ] || keep "$OUT/$name.failures.json" \
        $PY -m baselines.edp failures --policy "$policy" --episodes 200
    [ -s "$OUT/$name.validation.json" ] || keep "$OUT/$name.validation.json" \
        $PY -m baselines.edp failures --policy "$policy" --episodes 200 --validation
done
$PY - "$OUT" <<'PYEOF'
import json, pathlib, sys
out = pathlib.Path(sys.argv[1])
print("| policy | validation (200 starts) | eval (200 pinned starts) | failures' own draws | never lifted | opened | slipped | held at horizon | successes after a drop | reached the target | carry heads for the target |")
print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
for f in sorted(out.glob("*.failures.json")):
    name = f.name.removesuffix(".failures.json")
    fl = json.loads(f.read_text())
    e = out / f"{name}.eval.json"
    ev = json.loads(e.read_text()) if e.exists() else None
    v = out / f"{name}.validation.json"
    val = json.loads(v.read_text()) if v.exists() else None
    heads = lambda r: f"{r['toward_target']}/{r['carry_steps']}" if "carry_steps" in r else "-"
    rate = lambda r: f"{r['success_rate']:.3f} [{r['low']:.3f}, {r['high']:.3f}]"
    c = fl["counts"]
    print(f"| {name} | {rate(val) if val else '-'} | {rate(ev) if ev else '-'} | {rate(fl)} | {c.get('never lifted', 0)} | "
          f"{c.get('opened away', 0) + c.get('opened over target', 0)} | {c.get('slipped', 0)} | "
          f"{c.get('held at horizon', 0)} | {fl['successes_after_a_drop']} | {fl.get('reached_target', '-')} | "
          f"{heads(fl)} |")
PYEOF
