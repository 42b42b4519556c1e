"""The command line: one run, a sweep on Ray Tune, an ASHA screen, and reports next to the SB3
baselines.

    python -m equigym.steer run --method equi --task lift --seed 0 --steps 16000 --out runs/steer-rust
    python -m equigym.steer sweep --methods dsrl equi approx --tasks lift --seeds 0 1 2 3 4 --steps 16000 \\
        --out runs/sweep [--sb3 dsrl equi approx --sb3-seeds 0 1 2] [--cpus 2] [--address ray://host:10001] [--resume]
    python -m equigym.steer report --runs runs/sweep/rust [--sb3-runs runs/steer] --out docs/steering/rust
    python -m equigym.steer compare RUN_DIR ... --out docs/steering/x/compare.md   # with controls and intervals
    python -m equigym.steer screen --task stack --grid target_entropy=5,10,20 prior_kl=4 --steps 60000 \
        --eval-every 10000 --eval-episodes 100 --out runs/screen [--cpus 2] [--resume]   # ASHA early stopping

``run`` trains in-process in Rust (the GIL is released) and writes
``<out>/<task>/<method>/seed<S>/log.csv`` (``env_steps, success_rate, mean_q, seconds``, as the
SB3 runs), ``run.json``, ``summary.json`` (with a hash of the final weights) and
``checkpoint.bin``. Started again with the same arguments it resumes from the checkpoint and
ends bit for bit where an uninterrupted run ends; a larger ``--steps`` extends a finished run.
Results do not depend on ``--threads``.

``sweep`` runs methods x tasks x seeds as Ray Tune trials (``pip install 'equigym[sweep]'``):
local Ray by default, ``--address`` joins a cluster. Each trial advances its run one evaluation
interval at a time (each call resumes the agent's own checkpoint, so this changes nothing in the
results) and reports to Tune after each; ``--resume`` restores an interrupted sweep with
``Tuner.restore``. ``screen`` runs every combination of ``--grid``'s run options x seeds on one
method and task under Ray Tune's ASHA scheduler, which stops the trials whose recent success
falls behind (:func:`screen`). ``--sb3`` adds the SB3 + escnn baselines (``python -m baselines.steer run``, needs the
``train`` extra), written under ``<out>/sb3``; the Rust runs go under ``<out>/rust``.
"""

from __future__ import annotations

import argparse
import json

from equigym.steer.analysis import CONTROL_SCALES, compare, diagnose, report
from equigym.steer.runs import DEFAULT_EVAL, EDP_KERNELS, METHODS, RECIPES, TASKS, env_options, run, run_options
from equigym.steer.trials import screen, sweep


def add_run_arguments(s: argparse.ArgumentParser) -> None:
    """The run options every steering command shares, the Rust agents' and ``baselines.steer``'s
    (SB3) alike: joint limits, evaluation schedule, the EDP file and its kernel, terminate-on-success."""
    s.add_argument("--no-joint-limits", action="store_true")
    s.add_argument("--eval-every", type=int, default=DEFAULT_EVAL["eval_every"])
    s.add_argument("--eval-episodes", type=int, default=DEFAULT_EVAL["eval_episodes"])
    s.add_argument("--policy", default=None, help="EDP file (default: the shipped one)")
    s.add_argument(
        "--edp-kernel",
        choices=EDP_KERNELS,
        default=None,
        help="how the EDP's regular-to-regular layers run: in the Fourier basis (the default) or dense (the "
        "same map up to float rounding, several times slower; the kernel of runs recorded before the Fourier one, "
        "which replay only on it)",
    )
    s.add_argument(
        "--terminate-on-success",
        action="store_true",
        help="end training episodes at the first successful latent step (evaluation unchanged)",
    )


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(
        prog="python -m equigym.steer", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    sub = p.add_subparsers(dest="cmd", required=True)
    for name in ("run", "sweep", "screen"):
        s = sub.add_parser(name)
        if name == "screen":
            s.add_argument("--method", choices=METHODS, default="dsrl")
            s.add_argument("--task", choices=TASKS, default="lift")
            s.add_argument("--seeds", nargs="+", type=int, default=[0])
            s.add_argument(
                "--grid",
                nargs="+",
                required=True,
                help="run options to screen, each name=v1,v2,... (e.g. target_entropy=5,10,20 noise_aliased=0,1)",
            )
            s.add_argument("--recipe", choices=sorted(RECIPES), default="dsrl", help="options the grid adds to")
            s.add_argument("--grace", type=int, default=20_000, help="env steps before ASHA may stop a trial")
            s.add_argument("--reduction", type=int, default=3, help="ASHA's reduction factor")
        if name == "run":
            s.add_argument("--method", choices=METHODS, required=True)
            s.add_argument("--task", choices=TASKS, default="lift")
            s.add_argument("--seed", type=int, default=0)
            s.add_argument(
                "--threads", type=int, default=1, help="environment / denoising threads (results do not depend on it)"
            )
            s.add_argument("--controller", choices=("joint", "cartesian"), default=None)
            s.add_argument(
                "--env",
                default=None,
                help="environment options as JSON, the environments' keyword arguments (e.g. "
                '\'{"variant": "D2", "physics": {"substeps": 6}}\')',
            )
            s.add_argument("--horizon", type=int, default=None, help="episode length override (control steps)")
            s.add_argument("--quiet", action="store_true")
            s.add_argument("--out", default="runs/steer-rust")
            s.add_argument(
                "--recipe",
                choices=sorted(RECIPES),
                default="dsrl",
                help="named run options (RECIPES); flags add to them",
            )
        elif name == "sweep":
            s.add_argument("--methods", nargs="*", choices=METHODS, default=list(METHODS))
            s.add_argument("--sb3", nargs="*", choices=METHODS, default=None, help="SB3 + escnn methods to run as well")
            s.add_argument(
                "--sb3-seeds", nargs="+", type=int, default=None, help="seeds of the SB3 runs (default: --seeds)"
            )
            s.add_argument("--tasks", nargs="+", choices=TASKS, default=["lift"])
            s.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2, 3, 4])
        if name != "run":
            s.add_argument("--cpus", type=int, default=None, help="local Ray CPUs (default: all); one per trial")
            s.add_argument("--address", default=None, help="join a Ray cluster (e.g. ray://host:10001)")
            s.add_argument("--resume", action="store_true", help=f"restore an interrupted {name} (Tuner.restore)")
            s.add_argument("--out", default=f"runs/{name}")
        s.add_argument("--steps", type=int, default=20_000, help="primitive environment steps per run")
        s.add_argument("--preset", choices=("cpu", "paper"), default="cpu")
        add_run_arguments(s)
        s.add_argument(
            "--noise-aliased",
            action="store_true",
            help="DSRL-NA: an action-space critic trained by TD, the noise critic distilled from it (Rust agents)",
        )
        s.add_argument(
            "--target-entropy",
            type=float,
            default=None,
            help="the actor's target entropy (default: DSRL's 0; below the actor's maximum, 27.3 nats for a "
            "40-d latent; Rust agents)",
        )
        s.add_argument(
            "--prior-kl",
            type=float,
            default=None,
            help="regularise the actor towards the EDP's noise N(0, I) with this KL budget in nats, in place of "
            "the target entropy (Rust agents)",
        )
        s.add_argument(
            "--reward-scale",
            type=float,
            default=None,
            help="multiply the rewards the learner stores by this factor (default 1; evaluation unchanged; Rust agents)",
        )
        s.add_argument(
            "--select",
            type=int,
            default=None,
            help="steer by selection: the best of N fresh N(0, I) noises by the critics, no actor; the critics "
            "learn that policy's value (1: the base policy's; Rust agents)",
        )
        s.add_argument(
            "--utd",
            type=int,
            default=None,
            help="gradient steps per environment transition for every task (default: the preset's; Rust agents)",
        )
        s.add_argument(
            "--ent-init", type=float, default=None, help="initial entropy coefficient (default: the preset's)"
        )
    r = sub.add_parser("report")
    r.add_argument("--runs", default="runs/sweep/rust", help="Rust runs")
    r.add_argument("--sb3-runs", default=None, help="SB3 runs to show beside them")
    r.add_argument("--out", default="docs/steering/rust")
    cp = sub.add_parser("compare", help="runs beside the base and narrow-noise controls, with intervals")
    cp.add_argument("runs", nargs="+", help="run directories (.../<task>/<method>/seed<S>)")
    cp.add_argument("--scales", nargs="+", type=float, default=list(CONTROL_SCALES), help="control noise scales")
    cp.add_argument("--threads", type=int, default=1, help="control-evaluation threads (results do not depend on it)")
    cp.add_argument("--out", default=None, help="also write the table here (controls cached beside it)")
    cp.add_argument("--at", type=int, default=None, help="read every run as it stood at this many env steps")
    dg = sub.add_parser("diagnose", help="evaluations beside the learner's state (log.csv + train.csv) per run")
    dg.add_argument("runs", nargs="+", help="run directories (.../<task>/<method>/seed<S>)")
    dg.add_argument("--out", default=None, help="also write the tables to this Markdown file")
    a = p.parse_args(argv)
    if a.cmd == "report":
        report(a)
    elif a.cmd == "compare":
        print(compare(a.runs, tuple(a.scales), a.out, a.threads, a.at))
    elif a.cmd == "diagnose":
        print(diagnose(a.runs, a.out))
    elif a.cmd == "sweep":
        sweep(a)
    elif a.cmd == "screen":
        screen(a)
    else:
        options = run_options(a)
        s = run(
            a.method,
            a.task,
            a.seed,
            a.steps,
            a.out,
            threads=a.threads,
            preset=a.preset,
            env=env_options(a),
            eval_every=a.eval_every,
            eval_episodes=a.eval_episodes,
            policy=a.policy,
            edp_kernel=a.edp_kernel,
            ent_init=a.ent_init,
            progress=not a.quiet,
            **options,
        )
        print(json.dumps({k: v for k, v in s.items() if k != "rows"}, default=str))
