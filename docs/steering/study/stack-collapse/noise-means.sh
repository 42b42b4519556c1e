#!/usr/bin/env bash
# The direction the Stack D1 learners' noise takes (docs/steering.md, "Why Stack D1 falls as
# training starts"): each 32k study checkpoint found on this machine (the checkpoints are not
# committed) as a policy on 200 pinned starts, by its actor's samples and by its actor's mean
# (`steer eval --actor sampled|mean`), and the untrained learner of each method by its samples:
# the mean of every noise it picked and how much of its failing episodes stalled. Writes
# noise-means.jsonl and noise-means.md beside this script. About 1 min per evaluation on one core.
set -euo pipefail
cd "$(dirname "$0")/../../../.."
here=docs/steering/study/stack-collapse
study=docs/steering/study/runs/stack
R="--task stack --eval-every 4000 --terminate-on-success --noise-aliased --target-entropy 20 --policy assets/edp/stack.safetensors --edp-kernel dense --steps 32000 --threads 1 --episodes 200"
out=$here/noise-means.jsonl
: > $out
for m in dsrl equi approx; do
  for s in 0 1 2 3 4; do
    test -f $study/stack/$m/seed$s/checkpoint.bin || continue
    for a in sampled mean; do
      target/release/steer eval --method $m --seed $s $R --actor $a --out $study | sed "s/^{/{\"method\":\"$m\",\"seed\":$s,\"trained\":true,/" >> $out
    done
  done
  untrained=$(mktemp -d)   # an out directory with no checkpoint: the untrained learner
  target/release/steer eval --method $m --seed 2 $R --actor sampled --out "$untrained" | sed "s/^{/{\"method\":\"$m\",\"seed\":2,\"trained\":false,/" >> $out
done
python - "$out" > $here/noise-means.md <<'PY'
import json, sys
from equigym import _core
from equigym.envs import layout_slices
rows = [json.loads(line) for line in open(sys.argv[1])]
# The chunk's invariant coordinates under the planar rotation: each action's z and gripper width,
# found by name in the task's action layout.
spec = _core.Env("stack").spec
field = layout_slices(spec.action_layout)
D, Z, G = spec.action_dim, field["position"].start + 2, field["gripper_width"].start
print("# The Stack D1 learners' mean noise\n")
print("`bash docs/steering/study/stack-collapse/noise-means.sh`: each learner as a policy (its actor's samples, or its mean) on 200 "
      "pinned starts; the mean of every noise it picked (latent units, clipped to the box), its norm, the norm of its "
      "part on the chunk's rotation-invariant coordinates (each action's z and gripper width), and those coordinates "
      "for the chunk's 4 actions; *failures stalled*: over the failing episodes, the mean share of their chunks whose "
      "commanded hand position moved less than 2 mm from the previous chunk's (`failures_stalled`).\n")
print("| learner | seed | actor | success | failures stalled | mean noise norm | invariant part | z (4 actions) | gripper (4 actions) |")
print("|---|---:|---|---:|---:|---:|---:|---|---|")
for r in rows:
    if r["trained"] and r["trained_env_steps"] != 32000:
        continue  # a run still in progress
    m = r["noise_mean"]
    inv = [m[D * a + i] for a in range(len(m) // D) for i in (Z, G)]
    z = " ".join(f"{m[D * a + Z]:+.2f}" for a in range(len(m) // D))
    g = " ".join(f"{m[D * a + G]:+.2f}" for a in range(len(m) // D))
    label = r["method"] + ("" if r["trained"] else ", untrained")
    stalled = "-" if r["failures_stalled"] is None else f"{r['failures_stalled']:.3f}"
    print(f"| {label} | {r['seed']} | {r['actor']} | {r['rate']:.3f} | {stalled} | {r['noise_mean_norm']:.2f} | {sum(x * x for x in inv) ** 0.5:.2f} | {z} | {g} |")
PY
echo "$here/noise-means.md"
