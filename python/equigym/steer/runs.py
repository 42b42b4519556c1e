"""One steering run of the Rust agents, and the one reader of what it leaves on disk.

:func:`run` trains in-process in Rust (``equigym._core.steer_run``; the GIL is released) and
writes ``<out>/<task>/<method>/seed<S>/``: ``log.csv`` (``env_steps, success_rate, mean_q,
seconds``, as the SB3 runs), ``train.csv`` (the learner's state at each evaluation),
``run.json`` (the settings), ``summary.json`` (clocks, env steps, a hash of the final weights)
and ``checkpoint.bin``. Started again with the same arguments it resumes from the checkpoint
and ends bit for bit where an uninterrupted run ends; a larger ``steps`` extends a finished run.
The sweep, the study and the analysis read run directories only through :func:`read_run`,
:func:`run_summary` and :func:`run_steps`, so the layout has one home.
"""

from __future__ import annotations

import argparse
import csv
import json
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

#: run.json's evaluation settings when it does not name them (the runner's defaults).
DEFAULT_EVAL = {"eval_every": 2000, "eval_episodes": 50}
#: The run options that ``run.json`` records when set: switches, then options with a value.
RUN_OPTIONS = ("terminate_on_success", "noise_aliased", "target_entropy", "prior_kl", "reward_scale", "select", "utd")
VALUED_OPTIONS = ("target_entropy", "prior_kl", "reward_scale", "select", "utd")
#: How the EDP's regular-to-regular layers run (``_core.DiffusionPolicy``'s ``kernel``): the
#: first is the runtime's default; ``run.json`` names a kernel (``edp_kernel``) where it is not
#: dense, so a file that names none (every run recorded before the Fourier kernel) ran dense.
EDP_KERNELS = ("fourier", "dense")
#: The kernel of a ``run.json`` that names none.
UNNAMED_EDP_KERNEL = "dense"
COUNT_OPTIONS = ("select", "utd")


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
    edp_kernel, ent_init, utd, terminate_on_success, noise_aliased, target_entropy, prior_kl, reward_scale,
    select, progress);
    an unknown name is a ``TypeError``. ``policy`` defaults to the task's shipped EDP and
    ``progress`` to True."""
    options.setdefault("progress", True)
    return _core.steer_run(method, task, seed, steps, str(out), policy=_policy(task, policy), **options)


def run_summary(d: Path) -> dict[str, Any]:
    """Run directory ``d``'s ``summary.json`` (its env steps, clock and weights' hash); empty
    for a run that has not written one yet."""
    s = d / "summary.json"
    return json.loads(s.read_text()) if s.exists() else {}


def run_steps(d: Path) -> int:
    """The env steps run directory ``d`` has reached (:func:`run_summary`; 0 without one)."""
    return int(run_summary(d).get("env_steps", 0))


#: A run's checkpoint, the Rust runner's and the SB3 runner's (``baselines.steer``). Neither is
#: committed: a run paused on one machine starts over on another.
CHECKPOINTS = ("checkpoint.bin", "checkpoint/model.zip")


def resume_steps(d: Path) -> int:
    """The env steps run directory ``d`` continues from when it is advanced again: its
    :func:`run_steps` where its checkpoint is on this machine, else 0 (the runners start a run
    without a checkpoint afresh)."""
    return run_steps(d) if any((d / c).exists() for c in CHECKPOINTS) else 0


def read_run(d: Path) -> dict[str, Any]:
    with open(d / "log.csv", newline="") as f:
        log = list(csv.DictReader(f))
    train: dict[str, dict[str, str]] = {}
    if (d / "train.csv").exists():
        with open(d / "train.csv", newline="") as f:
            train = {r["env_steps"]: r for r in csv.DictReader(f)}
    meta = {**DEFAULT_EVAL, **(json.loads((d / "run.json").read_text()) if (d / "run.json").exists() else {})}
    return {"dir": d, "log": log, "train": train, "meta": meta}


def run_env(meta: dict[str, Any]) -> dict[str, Any]:
    """The environment options of a run from its ``run.json``."""
    env = dict(meta.get("env") or {})
    env.update({k: meta[k] for k in ("controller", "horizon", "variant") if meta.get(k) is not None})
    if not meta.get("joint_limits", True):
        env["joint_limits"] = False
    return env


def run_options(a: argparse.Namespace) -> dict[str, Any]:
    """The run options (``RUN_OPTIONS``) a command line asks for: its recipe's (``dsrl`` where the
    command has none), with its flags on top (a switch turns an option on, a value replaces)."""
    options = dict(RECIPES[getattr(a, "recipe", "dsrl")])
    for flag in ("terminate_on_success", "noise_aliased"):
        options[flag] = options.get(flag, False) or getattr(a, flag)
    for opt in VALUED_OPTIONS:
        if getattr(a, opt) is not None:
            options[opt] = getattr(a, opt)
    return options


def env_options(a: argparse.Namespace) -> dict[str, Any]:
    """The environment options (the environments' keyword arguments) a command line asks for:
    ``--env``'s JSON, with ``--no-joint-limits``, ``--controller`` and ``--horizon`` on top."""
    env = dict(json.loads(a.env)) if getattr(a, "env", None) else {}
    if a.no_joint_limits:
        env["joint_limits"] = False
    for name in ("controller", "horizon"):
        if getattr(a, name, None) is not None:
            env[name] = getattr(a, name)
    return env
