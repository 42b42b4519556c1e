"""Reading steering runs: their headline figures, the learner's state beside each evaluation,
and the fair comparison with the control arms (the base policy and narrow-noise bases on the
runs' own pinned evaluation starts and seeds), with standard errors over seeds and Wilson
intervals on pooled episodes.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

from equigym import _core
from equigym.steer.runs import RUN_OPTIONS, UNNAMED_EDP_KERNEL, VALUED_OPTIONS, read_run, run_env
from equigym.steer.stats import format_mean_se, format_pooled
from equigym.steer.sweep_report import write_report


def report(a: argparse.Namespace) -> str:
    """``python -m equigym.steer report``: Table 1 and plots of a sweep (:mod:`~equigym.steer.sweep_report`)."""
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
        run = read_run(d)
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


def _option_labels(meta: dict[str, Any]) -> list[str]:
    labels = [f"{k}={meta[k]}" if k in VALUED_OPTIONS else k for k in RUN_OPTIONS if k in meta]
    return labels + ([f"edp_kernel={meta['edp_kernel']}"] if "edp_kernel" in meta else [])


def _label(meta: dict[str, Any]) -> str:
    opts = _option_labels(meta)
    return meta["method"] + (f" ({', '.join(opts)})" if opts else "")


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
        **({"edp_kernel": meta["edp_kernel"]} if meta.get("edp_kernel") else {}),
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
                kw = {
                    "policy": settings["policy"],
                    "episodes": settings["episodes"],
                    "edp_kernel": settings.get("edp_kernel", UNNAMED_EDP_KERNEL),
                }
                known[key] = _core.evaluate_base(
                    meta["task"], seed=seed, scale=scale, threads=threads, env=run_env(meta), **kw
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
    read = [read_run(Path(d)) for d in runs]
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
            lines.append(f"| {name} | {len(evals)} | {per} | {format_mean_se(rates)} | {format_pooled(wins, total)} |")
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
                pooled = format_pooled(wins, total)
                lines.append(f"| {name} | {len(rs)} | {per} | {format_mean_se(per_seed)} | {pooled} |")
        lines.append("")
    text = "\n".join(lines)
    if out:
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        Path(out).write_text(text)
    return text
