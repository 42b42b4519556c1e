"""The headline experience: steer the shipped Lift EDP for a few minutes and show what steering
did, beside its controls on the same pinned evaluation starts (the README's main job).

    python -m baselines.headline                       # DSRL-NA recipe, 2 seeds x 16k env steps, Rust agents
    python -m baselines.headline --recipe dsrl --methods equi   # DSRL's own protocol (collapses)
    python -m baselines.headline --agents sb3 --methods equi   # the SB3 + escnn agents (DSRL's protocol only)

It runs the steering agents (resumable: a second call continues where the first stopped), then
prints ``equigym.steer compare``'s table: the base policy (latent noise N(0, I)) and the
narrow-noise bases N(0, s^2 I) evaluated with the runs' seeds, the untrained actor, the final
success (the last three evaluations) and the peak, as mean +- s.e. over seeds and pooled with
Wilson 95 % intervals; it writes ``<out>/report/compare.md``, ``table.md`` and ``lift.png``
(success rate and mean Q vs env steps).

The Rust agents (``equigym.steer``) are the default: they give the same log on every machine
and thread count, where the SB3 runs differ from one CPU to another. Each run is one thread;
``--workers`` runs that many at once (the Rust runs release the GIL, so threads suffice).
"""

from __future__ import annotations

import argparse
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from baselines import steer
from equigym.steer import RECIPES
from equigym.steer.stats import format_mean_se
from equigym.steer.sweep_report import LABELS, load_runs, write_report


def summary(out: Path, task: str, methods: list[str], base: float) -> str:
    """The before/after table: mean +- standard error over the seeds, and each seed's value (a
    single run is shown as that run alone); each run is labelled by its own run.json (Rust or SB3
    agent)."""
    rows = [f"{'':30s} {'success':>12s}", f"{'before (base EDP)':30s} {base:12.2f}"]
    for (run_task, key), runs in sorted(load_runs(out).items()):
        if run_task != task or key.removeprefix("rust-") not in methods:
            continue
        finals = [r["rows"][-1]["success_rate"] for r in runs]
        peaks = [max(row["success_rate"] for row in r["rows"]) for r in runs]
        for what, values in (("final", finals), ("peak", peaks)):
            seeds = ", ".join(f"{v:.2f}" for v in values)
            runs_said = f"{len(values)} seeds: {seeds}" if len(values) > 1 else "1 run"
            rows.append(f"{LABELS[key] + ' ' + what:30s} {format_mean_se(values, 2):>12s}   ({runs_said})")
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", default="lift", choices=sorted(steer.LATENT_IDS))
    p.add_argument("--methods", nargs="+", default=["dsrl"], choices=steer.METHODS)
    p.add_argument(
        "--recipe",
        default=None,
        choices=sorted(RECIPES),
        help="run options (equigym.steer.RECIPES; default na-tos-h20 for the Rust agents, dsrl for SB3)",
    )
    p.add_argument("--seeds", nargs="+", type=int, default=[0, 1])
    p.add_argument("--steps", type=int, default=16_000, help="environment steps per run")
    p.add_argument("--eval-every", type=int, default=2000)
    p.add_argument("--eval-episodes", type=int, default=100)
    p.add_argument("--ent-init", type=float, default=None)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--out", default=None, help="default runs/headline (Rust agents) or runs/headline-sb3")
    p.add_argument("--agents", choices=["rust", "sb3"], default="rust", help="Rust agents or the SB3 + escnn baselines")
    a = p.parse_args(argv)
    a.recipe = a.recipe or ("na-tos-h20" if a.agents == "rust" else "dsrl")
    if a.agents == "sb3" and RECIPES[a.recipe]:
        p.error(f"recipe {a.recipe} needs the Rust agents; use --recipe dsrl with --agents sb3")
    a.out = a.out or ("runs/headline" if a.agents == "rust" else "runs/headline-sb3")
    if a.agents == "rust":
        run_rust(a)
    else:
        run_sb3(a)
    report = Path(a.out) / "report"
    write_report(a.out, report)
    print()
    print(
        f"Steering the shipped {a.task} EDP ({a.steps:,} env steps per run, CPU preset, {a.agents} agents, "
        f"recipe {a.recipe}):"
    )
    if a.agents == "rust":
        from equigym import steer as rust_steer

        runs = [str(Path(a.out) / a.task / m / f"seed{s}") for m in a.methods for s in a.seeds]
        print(rust_steer.compare(runs, out=str(report / "compare.md"), threads=max(1, a.workers)))
    else:
        base = steer.base_success(a.task, a.out, a.eval_episodes)
        print(summary(Path(a.out), a.task, a.methods, base))
    print(f"tables and plot: {report}")


def run_rust(a: argparse.Namespace) -> None:
    from equigym import steer as rust_steer

    def one(job: tuple[str, int]) -> None:
        method, seed = job
        rust_steer.run(
            method,
            a.task,
            seed,
            a.steps,
            a.out,
            eval_every=a.eval_every,
            eval_episodes=a.eval_episodes,
            ent_init=a.ent_init,
            progress=a.workers == 1,
            **RECIPES[a.recipe],
        )

    jobs = [(m, s) for m in a.methods for s in a.seeds]
    with ThreadPoolExecutor(max_workers=max(1, a.workers)) as pool:
        list(pool.map(one, jobs))


def run_sb3(a: argparse.Namespace) -> None:
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


if __name__ == "__main__":
    main()
