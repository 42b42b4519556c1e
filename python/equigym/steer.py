"""Steering agents in Rust (DSRL, Equi-DSRL, Approx-Equi-DSRL): one run, a sweep on Ray Tune,
and a report next to the SB3 baselines.

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
import csv
import json
import math
import time
from pathlib import Path
from typing import Any

from equigym import _core

METHODS = ("dsrl", "equi", "approx")
TASKS = ("lift", "stack", "square")
#: Named bundles of run options. ``dsrl``: DSRL's own protocol (episodes run to the horizon,
#: a critic over noise, target entropy 0). ``na-tos-h20``: noise aliasing (an action-space
#: critic), training episodes that end at success, and a target entropy of +20 nats, wide but
#: within reach of the 40-d actor (at most 27.3 nats; docs/steering.md, "The recipe's target
#: entropy is out of reach": the earlier +40 never was, so its entropy coefficient grew without
#: end).
RECIPES: dict[str, dict[str, Any]] = {
    "dsrl": {},
    "na-tos-h20": {"noise_aliased": True, "terminate_on_success": True, "target_entropy": 20.0},
}


def _policy(task: str, policy: str | None) -> str:
    if policy is not None:
        return policy
    from equigym.latent import shipped_policy

    return str(shipped_policy(task))


def run(
    method: str,
    task: str = "lift",
    seed: int = 0,
    steps: int = 20_000,
    out: str | Path = "runs/steer-rust",
    *,
    policy: str | None = None,
    **options: Any,
) -> dict[str, Any]:
    """One Rust steering run (see the module docs); returns its summary (``run_dir``, ``rows``,
    ``env_steps``, ``grad_steps``, ``seconds``, ``seconds_by_activity`` (``rollout``,
    ``train``, ``eval``), ``eval_env_steps``, ``params_hash``, ``fields``, parameter counts).

    ``options`` are ``equigym._core.steer_run``'s keyword options, typed in its stub (threads,
    preset, env (the environments' keyword arguments as a dict), eval_every, eval_episodes,
    ent_init, utd, terminate_on_success, noise_aliased, target_entropy, prior_kl, reward_scale, select,
    progress);
    an unknown name is a ``TypeError``. ``policy`` defaults to the task's shipped EDP and
    ``progress`` to True."""
    options.setdefault("progress", True)
    return _core.steer_run(method, task, seed, steps, str(out), policy=_policy(task, policy), **options)


class Paused(RuntimeError):
    """A trial stopped at its invocation's deadline (``deadline`` in its config, epoch seconds):
    the run keeps its checkpoint, and restoring the experiment resumes it."""


def _trainable(config: dict[str, Any]) -> None:
    """One sweep trial: advance the run an evaluation interval at a time, report after each;
    past ``config["deadline"]`` (when given) stop between intervals with :class:`Paused`."""
    import tempfile

    from ray import tune

    c = config
    if _finished(c):
        return  # e.g. committed logs on a fresh machine, whose checkpoints are not in git
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
                ent_init=c["ent_init"],
                progress=False,
                **{k: c[k] for k in _OPTIONS if k in c},
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


def _finished(c: dict[str, Any]) -> bool:
    """Whether the trial's run already has all its env steps (its ``summary.json``, under the
    trial's own output root, whatever the task directory's name): such a trial returns at once,
    without its checkpoint (not committed) and past any deadline."""
    return any(run_steps(d) >= c["steps"] for d in Path(c["out"]).glob(f"*/{c['method']}/seed{c['seed']}"))


def run_summary(d: Path) -> dict[str, Any]:
    """Run directory ``d``'s ``summary.json`` (its env steps, clock and weights' hash); empty
    for a run that has not written one yet."""
    s = d / "summary.json"
    return json.loads(s.read_text()) if s.exists() else {}


def run_steps(d: Path) -> int:
    """The env steps run directory ``d`` has reached (:func:`run_summary`; 0 without one)."""
    return int(run_summary(d).get("env_steps", 0))


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


def _run_clocks(out: Path) -> dict[str, Any]:
    """The runs under ``out`` and the sum of their own clocks (each ``log.csv``'s last ``seconds``)."""
    clocks = []
    for log in sorted(out.glob("*/*/*/seed*/log.csv")):
        with open(log) as f:
            rows = list(csv.DictReader(f))
        if rows:
            clocks.append(float(rows[-1]["seconds"]))
    return {"runs": len(clocks), "run_seconds": round(sum(clocks), 1)}


def sweep(a: argparse.Namespace) -> None:
    if (a.noise_aliased or any(getattr(a, o) is not None for o in _VALUED)) and a.sb3:
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
        **_trial_settings(a, out),
        **_run_options(a),
    }

    def trainable(config: dict[str, Any]) -> None:
        c = {**config, **config["job"]}
        c["out"] = str(Path(c["out_root"]) / c["agent"])
        _trainable(c)

    _fit(a, trainable, space, "steer")


def _run_options(a: argparse.Namespace) -> dict[str, Any]:
    """The run options (``_OPTIONS``) a command line asks for: its recipe's (``dsrl`` where the
    command has none), with its flags on top (a switch turns an option on, a value replaces)."""
    options = dict(RECIPES[getattr(a, "recipe", "dsrl")])
    for flag in ("terminate_on_success", "noise_aliased"):
        options[flag] = options.get(flag, False) or getattr(a, flag)
    for opt in _VALUED:
        if getattr(a, opt) is not None:
            options[opt] = getattr(a, opt)
    return options


def _env_options(a: argparse.Namespace) -> dict[str, Any]:
    """The environment options (the environments' keyword arguments) a command line asks for:
    ``--env``'s JSON, with ``--no-joint-limits``, ``--controller`` and ``--horizon`` on top."""
    env = dict(json.loads(a.env)) if getattr(a, "env", None) else {}
    if a.no_joint_limits:
        env["joint_limits"] = False
    for name in ("controller", "horizon"):
        if getattr(a, name, None) is not None:
            env[name] = getattr(a, name)
    return env


def _trial_settings(a: argparse.Namespace, out: Path) -> dict[str, Any]:
    """What every trial of a sweep or a screen shares: budget, evaluation, policy and output root."""
    return {
        "steps": a.steps,
        "preset": a.preset,
        "env": _env_options(a),
        "eval_every": a.eval_every,
        "eval_episodes": a.eval_episodes,
        "policy": a.policy,
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
        runtime_env={"env_vars": {"PYTHONPATH": str(Path(__file__).resolve().parents[2])}} if pythonpath else None,
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
        record_invocation(record_path, entry, start=True, fresh=not a.resume, totals=_run_clocks(out))

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
    record_invocation(record_path, entry, start=False, totals=_run_clocks(out))
    print(f"{len(results)} trials, {len(failed)} failed, {wall:.0f} s wall")
    if failed:
        raise SystemExit(f"{len(failed)} trials failed; rerun with --resume")
    return results


def parse_grid(specs: list[str]) -> list[dict[str, Any]]:
    """``--grid name=v1,v2 ...`` as the list of every combination of run options. Names are the
    run options (``_OPTIONS``); switches take 0/1, the others numbers or ``none`` (unset: the
    recipe's value, e.g. ``prior_kl=none,4`` screens the recipe's entropy target against a KL
    budget)."""
    axes: list[tuple[str, list[Any]]] = []
    for spec in specs:
        name, _, values = spec.partition("=")
        if name not in _OPTIONS or not values:
            raise SystemExit(f"--grid takes name=v1,v2,... with a name in {_OPTIONS}, got '{spec}'")
        number = int if name in _COUNTS else float
        parse = (
            (lambda v, number=number: None if v == "none" else number(v))
            if name in _VALUED
            else (lambda v: {"0": False, "1": True}[v])
        )
        try:
            axes.append((name, [parse(v) for v in values.split(",")]))
        except (KeyError, ValueError):
            raise SystemExit(f"--grid {name}: {'numbers' if name in _VALUED else '0 or 1'}, got '{values}'") from None
    configs: list[dict[str, Any]] = [{}]
    for name, choices in axes:
        configs = [{**c, name: v} for c in configs for v in choices]
    return configs


def config_label(options: dict[str, Any]) -> str:
    """A directory name for a screen configuration: ``target_entropy-10.0_noise_aliased``."""
    parts = [f"{k}-{v}" if k in _VALUED else k for k, v in options.items() if v not in (False, None)]
    return "_".join(parts) or "default"


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
    base = _run_options(a)
    configs = []
    for c in parse_grid(a.grid):
        # the two regularisers exclude each other: the grid's replaces the recipe's
        inherited = {k: v for k, v in base.items() if not (k in _VALUED and any(c.get(g) is not None for g in _VALUED))}
        options = {**c, **{k: v for k, v in inherited.items() if c.get(k) is None}}  # the grid's options first
        configs.append({k: v for k, v in options.items() if v is not None})
    space = {
        "options": tune.grid_search(configs),
        "seed": tune.grid_search(a.seeds),
        "agent": "rust",
        "method": a.method,
        "task": a.task,
        **_trial_settings(a, out),
    }

    def trainable(config: dict[str, Any]) -> None:
        c = {**config, **config["options"]}
        c["out"] = str(Path(c["out_root"]) / config_label(config["options"]))
        _trainable(c)

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
        log = _read_run(d)["log"]
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


def report(a: argparse.Namespace) -> str:
    from equigym.report import write_report

    roots = [a.runs] + ([a.sb3_runs] if a.sb3_runs else [])
    text = write_report(roots, a.out)
    print(text)
    return text


#: train.csv columns shown by ``diagnose``, with their headers and formats.
_DIAGNOSTICS = (
    ("alpha", "entropy coef.", ".3f"),
    ("entropy", "policy entropy", ".1f"),
    ("edge_fraction", "at the edge", ".3f"),
    ("critic_loss", "critic loss", ".2f"),
    ("policy_q", "Q at the actor's actions", ".1f"),
    ("prior_kl", "KL to N(0, I)", ".1f"),
)


FINAL_EVALUATIONS = 3
# The summary's columns: figure and format.
FIGURES = (("untrained", ".2f"), ("peak", ".2f"), ("final", ".3f"))


def trained_rows(log: list[dict[str, str]], train: dict[str, dict[str, str]]) -> list[dict[str, str]]:
    """The evaluations (``log.csv`` rows) made once training had started: the entropy
    coefficient in ``train.csv`` has left its initial value. Before that the actor and the
    critics are their initialisation (and a peak is the warm-up's)."""
    alpha0 = train.get(log[0]["env_steps"], {}).get("alpha") if log else None
    return [r for r in log if alpha0 is not None and train.get(r["env_steps"], {}).get("alpha") not in (None, alpha0)]


def summarize(log: list[dict[str, str]], train: dict[str, dict[str, str]]) -> dict[str, float]:
    """A run's headline figures from its evaluations: ``untrained`` (the first evaluation, before
    any gradient step: the untrained actor), ``peak`` (the best evaluation once training has
    started, i.e. once the entropy coefficient in ``train.csv`` has left its initial value; a
    peak before that is the warm-up's, not a learned one) and ``final`` (the mean of the last
    ``FINAL_EVALUATIONS`` evaluations)."""
    rates = [float(r["success_rate"]) for r in log]
    trained = [float(r["success_rate"]) for r in trained_rows(log, train)]
    last = rates[-FINAL_EVALUATIONS:]
    return {
        "untrained": rates[0] if rates else float("nan"),
        "peak": max(trained) if trained else float("nan"),
        "final": sum(last) / len(last) if last else float("nan"),
    }


def diagnose(runs: list[str], out: str | None = None) -> str:
    """A summary of every run (untrained actor, peak once training started, final = mean of
    the last three evaluations; the options in ``run.json``), then one Markdown table per run
    directory: each evaluation (``log.csv``) beside the learner's state at that point
    (``train.csv``: what the Rust agents and ``baselines.steer`` record)."""

    def cell(v: str | None, fmt: str) -> str:
        return "" if v in (None, "", "nan") else format(float(v), fmt)

    summary = [
        "| run | method | options | untrained actor | peak after training starts | final (last 3) |",
        "|---|---|---|---:|---:|---:|",
    ]
    lines: list[str] = []
    for d in map(Path, runs):
        run = _read_run(d)
        log, train, meta = run["log"], run["train"], run["meta"]
        opts = ", ".join(_option_labels(meta)) or "-"
        s = summarize(log, train)
        summary.append(
            f"| `{d}` | {meta.get('method', '')} | {opts} | "
            + " | ".join("" if math.isnan(s[k]) else format(s[k], f) for k, f in FIGURES)
            + " |"
        )
        lines += [f"`{d}`", "", "| env steps | success | mean Q | " + " | ".join(h for _, h, _ in _DIAGNOSTICS) + " |"]
        lines.append("|" + "---:|" * (3 + len(_DIAGNOSTICS)))
        for r in log:
            t = train.get(r["env_steps"], {})
            cells = [r["env_steps"], cell(r["success_rate"], ".2f"), cell(r["mean_q"], ".1f")]
            cells += [cell(t.get(k), fmt) for k, _, fmt in _DIAGNOSTICS]
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
    text = "\n".join(summary + [""] + lines)
    if out:
        Path(out).write_text(text)
    return text


#: Noise scales of the control arms: the base policy (1) and narrow-noise bases N(0, s^2 I).
CONTROL_SCALES = (1.0, 0.5, 0.0)
#: run.json's evaluation settings when it does not name them (the runner's defaults).
_DEFAULT_EVAL = {"eval_every": 2000, "eval_episodes": 50}
#: The run options that ``run.json`` records when set: switches, then options with a value.
_OPTIONS = ("terminate_on_success", "noise_aliased", "target_entropy", "prior_kl", "reward_scale", "select", "utd")
_VALUED = ("target_entropy", "prior_kl", "reward_scale", "select", "utd")
_COUNTS = ("select", "utd")


def _read_run(d: Path) -> dict[str, Any]:
    with open(d / "log.csv", newline="") as f:
        log = list(csv.DictReader(f))
    train: dict[str, dict[str, str]] = {}
    if (d / "train.csv").exists():
        with open(d / "train.csv", newline="") as f:
            train = {r["env_steps"]: r for r in csv.DictReader(f)}
    meta = {**_DEFAULT_EVAL, **(json.loads((d / "run.json").read_text()) if (d / "run.json").exists() else {})}
    return {"dir": d, "log": log, "train": train, "meta": meta}


def _option_labels(meta: dict[str, Any]) -> list[str]:
    return [f"{k}={meta[k]}" if k in _VALUED else k for k in _OPTIONS if k in meta]


def _label(meta: dict[str, Any]) -> str:
    opts = _option_labels(meta)
    return meta["method"] + (f" ({', '.join(opts)})" if opts else "")


def _pooled(successes: int, n: int) -> str:
    low, high = _core.wilson(successes, n)
    return f"{successes}/{n} = {successes / n:.3f} [{low:.3f}, {high:.3f}]" if n else "-"


def mean_se(xs: list[float]) -> tuple[float, float]:
    """Mean and standard error of ``xs`` (nan where there are too few values)."""
    if not xs:
        return math.nan, math.nan
    m = sum(xs) / len(xs)
    if len(xs) < 2:
        return m, math.nan
    return m, math.sqrt(sum((x - m) ** 2 for x in xs) / (len(xs) - 1) / len(xs))


def _mean_se(xs: list[float]) -> str:
    m, se = mean_se(xs)
    if math.isnan(m):
        return "-"
    return f"{m:.3f}" if math.isnan(se) else f"{m:.3f} +- {se:.3f}"


def _meta_env(meta: dict[str, Any]) -> dict[str, Any]:
    """The environment options of a run from its ``run.json``."""
    env = dict(meta.get("env") or {})
    env.update({k: meta[k] for k in ("controller", "horizon", "variant") if meta.get(k) is not None})
    if not meta.get("joint_limits", True):
        env["joint_limits"] = False
    return env


def controls(
    meta: dict[str, Any],
    seeds: list[int],
    scales=CONTROL_SCALES,
    cache: Path | None = None,
    threads: int = 1,
    compute: bool = True,
) -> dict[float, list[dict[str, Any]]]:
    """The control arms of runs described by ``meta`` (run.json): the base policy with noise
    N(0, s^2 I) for each scale, one evaluation per seed on the runs' own evaluation starts and
    episode count (``_core.evaluate_base``). Cached in ``cache`` (JSON) by settings; with
    ``compute`` false only the cached evaluations are returned (a report that runs nothing)."""
    known: dict[str, Any] = json.loads(cache.read_text()) if cache and cache.exists() else {}
    settings = {
        "task": meta["task"],
        "policy": meta["policy"],
        "episodes": meta["eval_episodes"],
        "controller": meta.get("controller"),
        "joint_limits": meta.get("joint_limits", True),
        "horizon": meta.get("horizon"),
        "variant": meta.get("variant"),
        # keys of runs with further options only, so that committed caches keep their keys
        **({"env": meta["env"]} if meta.get("env") else {}),
    }
    out: dict[float, list[dict[str, Any]]] = {}
    for scale in scales:
        out[scale] = []
        # Without noise the base is deterministic: one evaluation stands for every seed.
        for seed in seeds if scale > 0 else seeds[:1]:
            key = json.dumps({**settings, "scale": scale, "seed": seed}, sort_keys=True)
            if key not in known and not compute:
                continue
            if key not in known:
                kw = {"policy": settings["policy"], "episodes": settings["episodes"]}
                known[key] = _core.evaluate_base(
                    meta["task"], seed=seed, scale=scale, threads=threads, env=_meta_env(meta), **kw
                )
                if cache:
                    cache.parent.mkdir(parents=True, exist_ok=True)
                    cache.write_text(json.dumps(known, indent=1) + "\n")
            out[scale].append(known[key])
    return out


def compare(
    runs: list[str], scales=CONTROL_SCALES, out: str | None = None, threads: int = 1, at: int | None = None
) -> str:
    """The fair comparison of steering runs with their controls, on the same pinned evaluation
    starts: per group of runs (method and options), the untrained actor (first evaluation) and
    the final success (mean of the last ``FINAL_EVALUATIONS`` evaluations) as mean +- s.e. over
    seeds and pooled over every final episode with a Wilson 95 % interval, and the peak once
    training started; beside them the base policy and the narrow-noise bases N(0, s^2 I) of the
    same settings and seeds (``controls``; cached in ``<out dir>/controls.json``). With ``at``,
    each run is read as it stood at that many env steps. The pooled
    intervals count episodes as independent, but every evaluation reuses the same starts, so
    they are narrower than the truth; the s.e. over seeds is the figure to compare methods by."""
    read = [_read_run(Path(d)) for d in runs]
    if at is not None:  # every run as it stood at `at` env steps (runs extended past it are cut)
        for r in read:
            r["log"] = [row for row in r["log"] if int(row["env_steps"]) <= at]
            if not r["log"]:
                raise ValueError(f"{r['dir']} has no evaluation at or before {at} env steps")
    groups: dict[tuple[str, str, str], list[dict[str, Any]]] = {}
    for r in read:
        m = r["meta"]
        groups.setdefault((m["task"], m["policy"], _label(m)), []).append(r)
    cache = Path(out).parent / "controls.json" if out else None
    lines = []
    for task, policy in sorted({(t, p) for t, p, _ in groups}):
        members = [g for g in groups if g[:2] == (task, policy)]
        first = groups[members[0]][0]["meta"]
        n = first["eval_episodes"]
        seeds = sorted({r["meta"]["seed"] for g in members for r in groups[g]})
        lines += [
            f"### {task}, `{policy}`",
            "",
            f"{n} episodes per evaluation on the pinned starts {_core.EVAL_SEED} + k; final = mean of the last "
            f"{FINAL_EVALUATIONS} evaluations; pooled = every final (or control) episode of every seed, Wilson 95 %.",
            "",
            "| arm | seeds | per seed | mean +- s.e. over seeds | pooled |",
            "|---|---:|---|---:|---:|",
        ]
        for scale, evals in controls(first, seeds, scales, cache, threads).items():
            name = "base policy, N(0, I)" if scale == 1.0 else f"narrow-noise base, N(0, {scale:g}^2 I)"
            rates = [e["success_rate"] for e in evals]
            wins, total = sum(e["successes"] for e in evals), sum(e["episodes"] for e in evals)
            per = ", ".join(f"{x:.2f}" for x in rates)
            lines.append(f"| {name} | {len(evals)} | {per} | {_mean_se(rates)} | {_pooled(wins, total)} |")
        for g in members:
            rs = sorted(groups[g], key=lambda r: r["meta"]["seed"])
            for what in ("untrained actor", "final", "peak after training starts"):
                per_seed, wins, total = [], 0, 0
                for r in rs:
                    k = r["meta"]["eval_episodes"]
                    rows = r["log"][:1] if what == "untrained actor" else r["log"][-FINAL_EVALUATIONS:]
                    if what.startswith("peak"):
                        per_seed.append(summarize(r["log"], r["train"])["peak"])
                        continue
                    counts = [round(float(x["success_rate"]) * k) for x in rows]
                    per_seed.append(sum(counts) / (k * len(counts)))
                    wins, total = wins + sum(counts), total + k * len(counts)
                steps = max(int(r["log"][-1]["env_steps"]) for r in rs)
                name = f"{g[2]}, {what}" + (f" ({steps:,} env steps)" if what == "final" else "")
                per = ", ".join(f"{x:.2f}" for x in per_seed)
                pooled = _pooled(wins, total) if total else "-"
                lines.append(f"| {name} | {len(rs)} | {per} | {_mean_se(per_seed)} | {pooled} |")
        lines.append("")
    text = "\n".join(lines)
    if out:
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        Path(out).write_text(text)
    return text


def add_run_arguments(s: argparse.ArgumentParser) -> None:
    """The run options every steering command shares, the Rust agents' and ``baselines.steer``'s
    (SB3) alike: joint limits, evaluation schedule, the EDP file, terminate-on-success."""
    s.add_argument("--no-joint-limits", action="store_true")
    s.add_argument("--eval-every", type=int, default=_DEFAULT_EVAL["eval_every"])
    s.add_argument("--eval-episodes", type=int, default=_DEFAULT_EVAL["eval_episodes"])
    s.add_argument("--policy", default=None, help="EDP file (default: the shipped one)")
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
        options = _run_options(a)
        s = run(
            a.method,
            a.task,
            a.seed,
            a.steps,
            a.out,
            threads=a.threads,
            preset=a.preset,
            env=_env_options(a),
            eval_every=a.eval_every,
            eval_episodes=a.eval_episodes,
            policy=a.policy,
            ent_init=a.ent_init,
            progress=not a.quiet,
            **options,
        )
        print(json.dumps({k: v for k, v in s.items() if k != "rows"}, default=str))


if __name__ == "__main__":
    main()
