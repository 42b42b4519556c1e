"""The headline experience: steer the shipped Lift EDP with Equi-DSRL for a few minutes and show
what steering did (the README's main job).

    python -m baselines.headline                       # 2 seeds x 10k env steps, ~10 min on 2 cores
    python -m baselines.headline --steps 40000 --seeds 0 1 2 --methods equi dsrl

It measures the base policy alone (latent noise N(0, I)), runs the steering agents (resumable:
a second call continues where the first stopped), prints the before/after table and writes
``<out>/report/table.md`` and ``<out>/report/lift.png`` (success rate and mean Q vs env steps).
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np

from baselines import steer
from baselines.report import LABELS, write_report


def summary(out: Path, task: str, methods: list[str], base: float) -> str:
    rows = [f"{'':22s} {'success':>8s}", f"{'before (base EDP)':22s} {base:8.2f}"]
    for m in methods:
        finals, peaks = [], []
        for log in sorted((out / task / m).glob("seed*/log.csv")):
            with open(log) as f:
                rates = [float(r["success_rate"]) for r in csv.DictReader(f)]
            if rates:
                finals.append(rates[-1])
                peaks.append(max(rates))
        if finals:
            rows.append(f"{LABELS[m] + ' final':22s} {np.mean(finals):8.2f}   ({len(finals)} seeds)")
            rows.append(f"{LABELS[m] + ' peak':22s} {np.mean(peaks):8.2f}")
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", default="lift", choices=sorted(steer.LATENT_IDS))
    p.add_argument("--methods", nargs="+", default=["equi"], choices=steer.METHODS)
    p.add_argument("--seeds", nargs="+", type=int, default=[0, 1])
    p.add_argument("--steps", type=int, default=10_000, help="environment steps per run")
    p.add_argument("--eval-every", type=int, default=2000)
    p.add_argument("--eval-episodes", type=int, default=50)
    p.add_argument("--ent-init", type=float, default=None)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--out", default="runs/headline")
    a = p.parse_args(argv)
    sweep_args = argparse.Namespace(
        methods=a.methods,
        tasks=[a.task],
        seeds=a.seeds,
        steps=a.steps,
        out=a.out,
        preset="cpu",
        ent_init=a.ent_init,
        no_joint_limits=False,
        eval_every=a.eval_every,
        eval_episodes=a.eval_episodes,
        policy=None,
        workers=a.workers,
        base_episodes=a.eval_episodes,
    )
    steer.sweep(sweep_args)
    base = steer.base_success(a.task, a.out, a.eval_episodes)
    write_report(a.out, Path(a.out) / "report")
    print()
    print(f"Steering the shipped {a.task} EDP ({a.steps:,} env steps per run, CPU preset):")
    print(summary(Path(a.out), a.task, a.methods, base))
    print(f"table and plot: {Path(a.out) / 'report'}")


if __name__ == "__main__":
    main()
