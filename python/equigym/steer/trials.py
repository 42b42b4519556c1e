"""Steering runs as Ray Tune trials: a sweep over methods x tasks x seeds, an ASHA screen of run
options, and the experiment plumbing the study shares (``equigym.study``).

Each trial (:func:`run_trial`) advances its run one evaluation interval at a time (each call
resumes the agent's own checkpoint, so this changes nothing in the results) and reports to Tune
after each; a restored experiment (``Tuner.restore``) picks up where its trials stopped, and
every invocation is recorded with its wall time (:func:`record_invocation`). Ray Tune does the
scheduling, the cluster (``--address``) and ASHA's early stopping; what is here is only what
ties it to equigym's runs.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import time
from pathlib import Path
from typing import Any

from equigym.steer.runs import (
    COUNT_OPTIONS,
    RUN_OPTIONS,
    VALUED_OPTIONS,
    env_options,
    read_run,
    resume_steps,
    run,
    run_options,
    run_steps,
)


class Paused(RuntimeError):
    """A trial stopped at its invocation's deadline (``deadline`` in its config, epoch seconds),
    or not started because it could not finish by then: the run keeps its checkpoint, and
    restoring the experiment resumes it."""


def run_trial(config: dict[str, Any]) -> None:
    """One sweep trial: advance the run an evaluation interval at a time, report after each;
    past ``config["deadline"]`` (when given) stop between intervals with :class:`Paused`. With
    ``config["cost_per_step"]`` (seconds per env step) as well, a run that would not reach its
    ``steps`` by the deadline from where it resumes is not started at all: on a machine that
    does not outlive the invocation, its progress would be lost with its checkpoint, and the CPU
    goes to a trial that fits instead."""
    import tempfile

    from ray import tune

    c = config
    if _finished(c):
        return  # e.g. committed logs on a fresh machine, whose checkpoints are not in git
    if c.get("deadline") is not None and c.get("cost_per_step") is not None:
        resumed = max((resume_steps(d) for d in _trial_runs(c)), default=0)
        need, left = (c["steps"] - resumed) * c["cost_per_step"], c["deadline"] - time.time()
        if need > left:
            raise Paused(f"not started: about {need / 60:.0f} min of work, {max(left, 0) / 60:.0f} min to the deadline")
    every = c["eval_every"]
    target = every
    while True:
        if c.get("deadline") is not None and time.time() > c["deadline"]:
            raise Paused(f"paused at the deadline before {min(target, c['steps'])} env steps")
        target = min(target, c["steps"])
        if c["agent"] == "rust":
            s = run(
                c["method"],
                c["task"],
                c["seed"],
                target,
                c["out"],
                threads=1,
                preset=c["preset"],
                env=c["env"],
                eval_every=every,
                eval_episodes=c["eval_episodes"],
                policy=c["policy"],
                edp_kernel=c.get("edp_kernel"),
                ent_init=c["ent_init"],
                progress=False,
                **{k: c[k] for k in RUN_OPTIONS if k in c},
            )
            rows = [tuple(r) for r in s["rows"]]
            last = rows[-1] if rows else (0, float("nan"), float("nan"), 0.0)
            metrics = {"env_steps": last[0], "success_rate": last[1], "mean_q": last[2], "run_seconds": s["seconds"]}
        else:
            d = _run_sb3(c, target)
            lines = (d / "log.csv").read_text().strip().splitlines()[1:]
            rows = [tuple(float(v) for v in line.split(",")) for line in lines]
            last = rows[-1] if rows else (0, float("nan"), float("nan"), 0.0)
            metrics = {"env_steps": int(last[0]), "success_rate": last[1], "mean_q": last[2], "run_seconds": last[3]}
        # What a scheduler compares: the mean of the last two evaluations after training started
        # (one 100-episode evaluation has a standard error of about 0.05).
        trained = [r[1] for r in rows[1:]]
        metrics["success_recent"] = sum(trained[-2:]) / len(trained[-2:]) if trained else float("nan")
        # The agent keeps its own checkpoint; Tune's marks how far the trial got.
        with tempfile.TemporaryDirectory() as tmp:
            Path(tmp, "progress.json").write_text(json.dumps({"steps": target}))
            tune.report(metrics, checkpoint=tune.Checkpoint.from_directory(tmp))
        if target >= c["steps"]:
            return
        target += every


def _trial_runs(c: dict[str, Any]) -> list[Path]:
    """The trial's run directory under its own output root, whatever the task directory's name
    (none before the run has started)."""
    return sorted(Path(c["out"]).glob(f"*/{c['method']}/seed{c['seed']}"))


def _finished(c: dict[str, Any]) -> bool:
    """Whether the trial's run already has all its env steps (its ``summary.json``): such a
    trial returns at once, without its checkpoint (not committed) and past any deadline."""
    return any(run_steps(d) >= c["steps"] for d in _trial_runs(c))


def _run_sb3(c: dict[str, Any], steps: int) -> Path:
    """Advance one SB3 + escnn run to ``steps`` with its command, ``python -m baselines.steer run``:
    that runner lives in the source checkout, not in the package, which imports nothing from it
    (the sweep puts the checkout on its trials' ``PYTHONPATH``). Returns the run's directory."""
    import subprocess
    import sys

    cmd = [sys.executable, "-m", "baselines.steer", "run", "--method", c["method"], "--task", c["task"]]
    cmd += ["--seed", str(c["seed"]), "--steps", str(steps), "--out", str(c["out"]), "--preset", c["preset"]]
    cmd += ["--eval-every", str(c["eval_every"]), "--eval-episodes", str(c["eval_episodes"]), "--no-progress"]
    if c["ent_init"] is not None:
        cmd += ["--ent-init", repr(float(c["ent_init"]))]
    limits = c["env"].get("joint_limits", True)
    if set(c["env"]) - {"joint_limits"}:
        raise SystemExit(f"the SB3 runner takes no environment options but joint_limits, got {c['env']}")
    if not limits:
        cmd.append("--no-joint-limits")
    if c["policy"]:
        cmd += ["--policy", str(c["policy"])]
    if c.get("edp_kernel"):
        cmd += ["--edp-kernel", c["edp_kernel"]]
    if c.get("terminate_on_success"):
        cmd.append("--terminate-on-success")
    subprocess.run(cmd, check=True)
    return Path(c["out"]) / f"{c['task']}{'' if limits else '-nolimits'}" / c["method"] / f"seed{c['seed']}"


def sweep_jobs(methods: list[str], seeds: list[int], sb3: list[str], sb3_seeds: list[int]) -> list[dict[str, Any]]:
    """The sweep's (agent, method, seed) jobs, seed-major across both agents, so that early
    results cover every method of each."""
    jobs = []
    for s in sorted(set(seeds) | set(sb3_seeds)):
        jobs += [{"agent": "rust", "method": m, "seed": s} for m in methods if s in seeds]
        jobs += [{"agent": "sb3", "method": m, "seed": s} for m in sb3 if s in sb3_seeds]
    return jobs


def record_invocation(
    path: Path, entry: dict[str, Any], *, start: bool, fresh: bool = False, totals: dict[str, Any] | None = None
) -> None:
    """The record of a sweep's or a study's invocations (``sweep.json``, ``study.json``): one
    entry per invocation, written when it starts (``start``; ``fresh`` drops the earlier ones)
    and completed when it ends, so that a resumed experiment's wall time adds up (a killed
    invocation keeps its start only); ``wall_seconds`` sums the finished ones, ``totals`` adds
    the caller's own figures."""
    record = json.loads(path.read_text()) if path.exists() and not fresh else {}
    invocations = record.get("invocations", [])
    if start or not invocations:
        invocations.append(entry)
    else:
        invocations[-1].update(entry)
    wall = round(sum(i.get("wall_seconds", 0.0) for i in invocations), 1)
    path.write_text(json.dumps({"invocations": invocations, "wall_seconds": wall, **(totals or {})}, indent=1) + "\n")


def run_clocks(out: Path) -> dict[str, Any]:
    """The runs under ``out`` and the sum of their own clocks (each ``log.csv``'s last ``seconds``)."""
    clocks = []
    for log in sorted(out.glob("*/*/*/seed*/log.csv")):
        with open(log) as f:
            rows = list(csv.DictReader(f))
        if rows:
            clocks.append(float(rows[-1]["seconds"]))
    return {"runs": len(clocks), "run_seconds": round(sum(clocks), 1)}


def trial_settings(a: argparse.Namespace, out: Path) -> dict[str, Any]:
    """What every trial of a sweep or a screen shares: budget, evaluation, policy and output root."""
    return {
        "steps": a.steps,
        "preset": a.preset,
        "env": env_options(a),
        "eval_every": a.eval_every,
        "eval_episodes": a.eval_episodes,
        "policy": a.policy,
        "edp_kernel": a.edp_kernel,
        "ent_init": a.ent_init,
        "out_root": str(out),
    }


def tune_experiment(
    trainable: Any,
    space: dict[str, Any],
    name: str,
    storage: Path,
    *,
    address: str | None,
    cpus: int | None,
    restore: bool,
    pythonpath: bool = False,
    scheduler: Any = None,
    before_fit: Any = None,
) -> tuple[Any, bool]:
    """Run the Tune experiment ``name`` under ``storage``, one CPU per trial, or restore it
    (``Tuner.restore``, errored trials resumed) where ``restore`` and Tune can; ``pythonpath``
    puts the checkout on the trials' path (for runners that live there). ``before_fit(restored)``
    runs once the experiment is set up. Returns the results and whether it was restored."""
    import ray
    from ray import tune

    # "local": a fresh instance of `cpus` CPUs, even when another Ray instance runs on this
    # machine (with no address Ray would join that one).
    ray.init(
        address=address or "local",
        num_cpus=cpus if address is None else None,
        ignore_reinit_error=True,
        runtime_env={"env_vars": {"PYTHONPATH": str(Path(__file__).resolve().parents[3])}} if pythonpath else None,
    )
    try:
        resources = tune.with_resources(trainable, {"cpu": 1})
        restored = restore and tune.Tuner.can_restore(str(storage / name))
        if restored:
            tuner = tune.Tuner.restore(str(storage / name), resources, resume_errored=True)
        else:
            tuner = tune.Tuner(
                resources,
                param_space=space,
                tune_config=tune.TuneConfig(scheduler=scheduler),
                run_config=tune.RunConfig(name=name, storage_path=str(storage), verbose=1),
            )
        if before_fit is not None:
            before_fit(restored)
        return tuner.fit(), restored
    finally:
        ray.shutdown()


def _fit(a: argparse.Namespace, trainable: Any, space: dict[str, Any], name: str, scheduler: Any = None) -> Any:
    """Run (or, with ``--resume``, restore) the Tune experiment ``name`` under ``<out>/tune``
    (:func:`tune_experiment`), and keep ``<out>/sweep.json``'s record of invocations
    (:func:`record_invocation`); returns the results."""
    out = Path(a.out).resolve()
    started = time.time()
    record_path = out / "sweep.json"

    def started_record(restored: bool) -> None:
        entry = {"started": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "args": vars(a), "restored": restored}
        record_invocation(record_path, entry, start=True, fresh=not a.resume, totals=run_clocks(out))

    results, _ = tune_experiment(
        trainable,
        space,
        name,
        out / "tune",
        address=a.address,
        cpus=a.cpus,
        restore=a.resume,
        pythonpath=bool(getattr(a, "sb3", None)),
        scheduler=scheduler,
        before_fit=started_record,
    )
    wall = time.time() - started
    failed = [r for r in results if r.error is not None]
    entry = {"wall_seconds": round(wall, 1), "trials": len(results), "failed": len(failed)}
    record_invocation(record_path, entry, start=False, totals=run_clocks(out))
    print(f"{len(results)} trials, {len(failed)} failed, {wall:.0f} s wall")
    if failed:
        raise SystemExit(f"{len(failed)} trials failed; rerun with --resume")
    return results


def parse_grid(specs: list[str]) -> list[dict[str, Any]]:
    """``--grid name=v1,v2 ...`` as the list of every combination of run options. Names are the
    run options (``RUN_OPTIONS``); switches take 0/1, the others numbers or ``none`` (unset: the
    recipe's value, e.g. ``prior_kl=none,4`` screens the recipe's entropy target against a KL
    budget)."""
    axes: list[tuple[str, list[Any]]] = []
    for spec in specs:
        name, _, values = spec.partition("=")
        if name not in RUN_OPTIONS or not values:
            raise SystemExit(f"--grid takes name=v1,v2,... with a name in {RUN_OPTIONS}, got '{spec}'")
        number = int if name in COUNT_OPTIONS else float
        parse = (
            (lambda v, number=number: None if v == "none" else number(v))
            if name in VALUED_OPTIONS
            else (lambda v: {"0": False, "1": True}[v])
        )
        try:
            axes.append((name, [parse(v) for v in values.split(",")]))
        except (KeyError, ValueError):
            raise SystemExit(
                f"--grid {name}: {'numbers' if name in VALUED_OPTIONS else '0 or 1'}, got '{values}'"
            ) from None
    configs: list[dict[str, Any]] = [{}]
    for name, choices in axes:
        configs = [{**c, name: v} for c in configs for v in choices]
    return configs


def config_label(options: dict[str, Any]) -> str:
    """A directory name for a screen configuration: ``target_entropy-10.0_noise_aliased``."""
    parts = [f"{k}-{v}" if k in VALUED_OPTIONS else k for k, v in options.items() if v not in (False, None)]
    return "_".join(parts) or "default"


def sweep(a: argparse.Namespace) -> None:
    if (a.noise_aliased or any(getattr(a, o) is not None for o in VALUED_OPTIONS)) and a.sb3:
        raise SystemExit(
            "--noise-aliased, --target-entropy, --prior-kl, --reward-scale and --select are Rust-agent options; "
            "drop --sb3 or them"
        )
    try:
        from ray import tune
    except ImportError as e:  # pragma: no cover
        raise SystemExit("the sweep needs Ray Tune: pip install 'equigym[sweep]' (or 'ray[tune]')") from e
    out = Path(a.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    jobs = sweep_jobs(a.methods, a.seeds, a.sb3 or [], a.sb3_seeds if a.sb3_seeds is not None else a.seeds)
    space = {
        "job": tune.grid_search(jobs),
        "task": tune.grid_search(a.tasks),
        **trial_settings(a, out),
        **run_options(a),
    }

    def trainable(config: dict[str, Any]) -> None:
        c = {**config, **config["job"]}
        c["out"] = str(Path(c["out_root"]) / c["agent"])
        run_trial(c)

    _fit(a, trainable, space, "steer")


def screen(a: argparse.Namespace) -> None:
    """Screen run options (``--grid``) on short runs with Ray Tune's ASHA scheduler: every
    configuration x seed is a trial that reports after each evaluation; a trial whose recent
    success (mean of its last two evaluations) is below the top ``1/--reduction`` of the trials
    that reached the same step is stopped at the rungs ``--grace`` x reduction^k env steps. Each
    trial's run lies under ``<out>/<configuration>/``; ``screen.md`` tabulates every evaluation."""
    try:
        from ray import tune
        from ray.tune.schedulers import ASHAScheduler
    except ImportError as e:  # pragma: no cover
        raise SystemExit("the screen needs Ray Tune: pip install 'equigym[sweep]' (or 'ray[tune]')") from e
    out = Path(a.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    base = run_options(a)
    configs = []
    for c in parse_grid(a.grid):
        # the two regularisers exclude each other: the grid's replaces the recipe's
        inherited = {
            k: v
            for k, v in base.items()
            if not (k in VALUED_OPTIONS and any(c.get(g) is not None for g in VALUED_OPTIONS))
        }
        options = {**c, **{k: v for k, v in inherited.items() if c.get(k) is None}}  # the grid's options first
        configs.append({k: v for k, v in options.items() if v is not None})
    space = {
        "options": tune.grid_search(configs),
        "seed": tune.grid_search(a.seeds),
        "agent": "rust",
        "method": a.method,
        "task": a.task,
        **trial_settings(a, out),
    }

    def trainable(config: dict[str, Any]) -> None:
        c = {**config, **config["options"]}
        c["out"] = str(Path(c["out_root"]) / config_label(config["options"]))
        run_trial(c)

    scheduler = ASHAScheduler(
        time_attr="env_steps",
        metric="success_recent",
        mode="max",
        max_t=a.steps,
        grace_period=a.grace,
        reduction_factor=a.reduction,
    )
    _fit(a, trainable, space, "screen", scheduler)
    text = screen_table(out, a.task, a.method)
    (out / "screen.md").write_text(text)
    print(text)


def screen_table(out: Path, task: str, method: str) -> str:
    """Every screened configuration's evaluations (``log.csv``), best recent success first."""
    rows = []
    for d in sorted(out.glob(f"*/{task}*/{method}/seed*")):
        log = read_run(d)["log"]
        rates = [float(r["success_rate"]) for r in log]
        recent = rates[1:][-2:]
        rows.append(
            (
                sum(recent) / len(recent) if recent else float("nan"),
                d.relative_to(out).parts[0],
                d.name,
                ", ".join(f"{r['env_steps']}: {float(r['success_rate']):.2f}" for r in log),
            )
        )
    rows.sort(key=lambda r: -r[0] if not math.isnan(r[0]) else math.inf)
    lines = [
        f"# Screen: {task}, {method}",
        "",
        "recent = mean of the last two evaluations after training started; a run that ends early was stopped by ASHA.",
        "",
        "| configuration | seed | recent | evaluations (env steps: success) |",
        "|---|---|---:|---|",
    ]
    lines += [f"| {label} | {seed} | {recent:.3f} | {evals} |" for recent, label, seed, evals in rows]
    return "\n".join(lines) + "\n"
