"""Every table and figure of the study (:mod:`equigym.study`), rebuilt from its files alone.

    python -m equigym.study report [--out docs/steering/study] [--update-docs]

Reads ``<out>/runs/<cell>/.../seed<S>/{log,train}.csv`` and ``run.json``, the cached control
arms (``runs/<cell>/controls.json``), the dial's breaking measures (``breaking/<cell>.json``) and
``study.json``; runs nothing. A cell with no runs yet shows ``-``, so a study in progress
reports what it has; a run counts once it has reached its cell's budget. Writes ``report.md``,
``success.png``, ``mean_q.png`` and ``dial.png``; ``--update-docs`` also writes the report's body
(Table 1, figures, ablations, dial, the claims' evidence) into ``docs/steering.md``'s ``study``
block and Table 1's peak and final rows into the README's ``study-summary`` block.

The claims' evidence reads every gain and difference by one stated rule (more than two
standard errors over at least 3 seeds), so that the verdicts move with the logs and no number
in the prose is typed by hand.

Figures per run: *untrained* (the first evaluation, before any gradient step), *peak* (the best
evaluation once training has started: the paper's metric, biased upward by the choice among
noisy evaluations), *final* (the mean of the last three evaluations). Across seeds: mean +-
standard error. Pooled: every final episode of every seed, Wilson 95 % (the evaluations reuse
the same pinned starts, so these intervals are narrower than the truth; compare methods by the
s.e. over seeds). The steering *gain* of a run is its final success minus the base policy's on
the same starts with the same seed's noise stream.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

from equigym.steer import (
    CONTROL_SCALES,
    FINAL_EVALUATIONS,
    controls,
    read_run,
    run_summary,
    summarize,
    trained_rows,
)
from equigym.steer.stats import format_mean_se, format_pooled, mean_se
from equigym.study.cells import CELLS, LABELS, PAPER, PARTS, ROOT, TASK_LABELS, Cell, budget, run_dirs


def load_cell(cell: Cell, root: Path) -> dict[str, Any]:
    """A cell's runs by method (each with its figures and final successes) and its controls."""
    runs: dict[str, list[dict[str, Any]]] = {}
    meta = None
    for d in run_dirs(cell, root):
        r = read_run(d)
        if not r["log"] or int(r["log"][-1]["env_steps"]) < cell.steps:
            continue  # a run in progress counts once it reaches the cell's budget
        m = r["meta"]
        meta = meta or m
        k = int(m.get("eval_episodes", cell.eval_episodes))
        last = r["log"][-FINAL_EVALUATIONS:]
        wins = sum(round(float(x["success_rate"]) * k) for x in last)
        runs.setdefault(m["method"], []).append(
            {
                "seed": int(m["seed"]),
                "log": r["log"],
                # mean Q once training had started (before it, the critic's initialisation)
                "trained_q": [float(row["mean_q"]) for row in trained_rows(r["log"], r["train"])],
                "steps": int(r["log"][-1]["env_steps"]),
                "figures": summarize(r["log"], r["train"]),
                "final_wins": wins,
                "final_n": k * len(last),
                "summary": run_summary(d),
            }
        )
    for rs in runs.values():
        rs.sort(key=lambda r: r["seed"])
    ctl: dict[float, dict[int, dict[str, Any]]] = {}
    cache = cell.out(root) / "controls.json"
    if meta is not None and cache.exists():
        got = controls(meta, list(cell.seeds), CONTROL_SCALES, cache, compute=False)
        ctl = {s: {e["seed"]: e for e in evals} for s, evals in got.items()}
    return {"cell": cell, "runs": runs, "controls": ctl}


def _control_rates(data: dict[str, Any], scale: float) -> list[float]:
    return [e["success_rate"] for e in data["controls"].get(scale, {}).values()]


def _best_narrow(data: dict[str, Any]) -> tuple[float | None, list[float]]:
    """The narrow-noise base (scale < 1) with the highest mean success, and its rates."""
    best: tuple[float | None, list[float]] = (None, [])
    for s in CONTROL_SCALES:
        rates = _control_rates(data, s)
        if s < 1.0 and rates and (best[0] is None or mean_se(rates)[0] > mean_se(best[1])[0]):
            best = (s, rates)
    return best


def gains(data: dict[str, Any], method: str) -> list[float]:
    """Final success minus the base's on the same seed, per seed that has both."""
    base = data["controls"].get(1.0, {})
    return [
        r["figures"]["final"] - base[r["seed"]]["success_rate"]
        for r in data["runs"].get(method, [])
        if r["seed"] in base
    ]


def _pooled_final(runs: list[dict[str, Any]]) -> str:
    """The runs' final evaluations pooled, with a Wilson interval."""
    return format_pooled(sum(r["final_wins"] for r in runs), sum(r["final_n"] for r in runs), counts=False)


def expected_peak(p: float, n: int, k: int) -> float:
    """The expected best of ``k`` evaluations of ``n`` episodes each of a policy that succeeds
    with probability ``p`` and learns nothing: E[max of k Binomial(n, p)] / n."""
    cdf, below, total = 0.0, 0.0, 0.0
    for x in range(n + 1):
        cdf += math.comb(n, x) * p**x * (1.0 - p) ** (n - x)
        top = min(cdf, 1.0) ** k
        total += x / n * (top - below)
        below = top
    return total


def base_peaks(data: dict[str, Any]) -> list[float]:
    """Per seed with runs, the peak the base policy alone would show under the runs' selection:
    :func:`expected_peak` at the seed's base rate, the cell's evaluation size and the number of
    evaluations the runs' peak is taken over."""
    base = data["controls"].get(1.0, {})
    k: dict[int, int] = {}
    for rs in data["runs"].values():
        for r in rs:
            k[r["seed"]] = max(k.get(r["seed"], 0), len(r["trained_q"]))
    n = data["cell"].eval_episodes
    return [expected_peak(base[s]["success_rate"], n, k[s]) for s in sorted(k) if s in base and k[s]]


def peak_excess(data: dict[str, Any], method: str) -> list[float]:
    """A method's peak minus the base's own peak (:func:`expected_peak`), per seed with both."""
    base, n = data["controls"].get(1.0, {}), data["cell"].eval_episodes
    return [
        r["figures"]["peak"] - expected_peak(base[r["seed"]]["success_rate"], n, len(r["trained_q"]))
        for r in data["runs"].get(method, [])
        if r["seed"] in base and r["trained_q"] and not math.isnan(r["figures"]["peak"])
    ]


def trend(run: dict[str, Any]) -> float:
    """Whether a run's success had levelled off at its budget: the mean of its last
    ``FINAL_EVALUATIONS`` evaluations minus the mean of as many before them (nan if too few)."""
    rates = [float(r["success_rate"]) for r in run["log"]]
    k = FINAL_EVALUATIONS
    if len(rates) < 2 * k + 1:  # the first evaluation is the untrained actor's
        return math.nan
    return sum(rates[-k:]) / k - sum(rates[-2 * k : -k]) / k


def table1(cells: dict[str, dict[str, Any]]) -> list[str]:
    lines = []
    for figure, title in (
        ("peak", "Peak success (the paper's metric)"),
        ("final", "Final success (mean of the last 3 evaluations)"),
    ):
        peak = figure == "peak"
        lines += [
            f"**{title}**, mean +- s.e. over seeds (seeds); the paper's figure in brackets"
            + ("; *base's own peak*: the expected best of as many evaluations of the base alone" if peak else ""),
            "",
            "| task | base N(0, I) | "
            + ("base's own peak | " if peak else "")
            + "best narrow-noise base | "
            + " | ".join(LABELS.values())
            + " |",
            "|---|---:|" + ("---:|" if peak else "") + "---:|" + "---:|" * len(LABELS),
        ]
        for name in PARTS["table1"]:
            d = cells[name]
            task = d["cell"].task
            scale, narrow = _best_narrow(d)
            row = [
                f"{TASK_LABELS[task]} ({d['cell'].steps:,} steps)",
                f"{format_mean_se(_control_rates(d, 1.0), count=True)} [{PAPER[task]['base']:.3f}]",
                *([format_mean_se(base_peaks(d), count=True)] if peak else []),
                f"{format_mean_se(narrow, count=True)}" + (f" (s = {scale:g})" if scale is not None else ""),
            ]
            for m in LABELS:
                xs = [r["figures"][figure] for r in d["runs"].get(m, []) if not math.isnan(r["figures"][figure])]
                row.append(format_mean_se(xs, count=True) + (f" [{PAPER[task][m]:.3f}]" if figure == "peak" else ""))
            lines.append("| " + " | ".join(row) + " |")
        lines.append("")
    lines += [
        "**Untrained actor, pooled final evaluations, gain over the base** (final - base, paired by seed) **and "
        "whether the curves had levelled off at the budget**",
        "",
        "| task | method | untrained actor | final, pooled (Wilson 95 %) | gain over the base | still moving? "
        "(last 3 - the 3 before) | env steps |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    for name in PARTS["table1"]:
        d = cells[name]
        for m, label in LABELS.items():
            rs = d["runs"].get(m, [])
            steps = ", ".join(sorted({f"{r['steps']:,}" for r in rs})) or "-"
            untrained = [r["figures"]["untrained"] for r in rs]
            trends = [x for x in map(trend, rs) if not math.isnan(x)]
            cols = [format_mean_se(xs, count=True) for xs in (untrained, gains(d, m), trends)]
            lines.append(
                f"| {TASK_LABELS[d['cell'].task]} | {label} | {cols[0]} | {_pooled_final(rs)} | {cols[1]} | {cols[2]} | "
                f"{steps} |"
            )
    return lines + [""]


def comparison(cells: dict[str, dict[str, Any]], names: tuple[str, ...], title: str) -> list[str]:
    """One row per cell: its base, best narrow base, and each method's final and gain."""
    lines = [
        f"**{title}**",
        "",
        "| setting | base N(0, I) | best narrow-noise base | "
        + " | ".join(f"{v} final / gain" for v in LABELS.values())
        + " |",
        "|---|---:|---:|" + "---:|" * len(LABELS),
    ]
    for name in names:
        d = cells[name]
        scale, narrow = _best_narrow(d)
        row = [
            f"{d['cell'].label} ({d['cell'].steps // 1000}k steps)",
            format_mean_se(_control_rates(d, 1.0), count=True),
            format_mean_se(narrow, count=True) + (f" (s = {scale:g})" if scale else ""),
        ]
        for m in LABELS:
            finals = [r["figures"]["final"] for r in d["runs"].get(m, [])]
            row.append(f"{format_mean_se(finals, count=True)} / {format_mean_se(gains(d, m))}" if finals else "-")
        lines.append("| " + " | ".join(row) + " |")
    return lines + [""]


def breaking_of(root: Path, cell: Cell) -> dict[str, float] | None:
    """The dial's measure for a cell: the expert's rotated demonstrations replayed (the share
    that fails), the hand error of step(g s, g a) against g step(s, a), the unreachable share."""
    from equigym.symmetry import summarize as summarize_breaking

    path = root / "breaking" / f"{cell.name}.json"
    if not path.exists():
        return None
    s = summarize_breaking(json.loads(path.read_text()))
    return {
        "replay_failure": 1.0 - s["rotated_replay_success"],
        "hand_error_mm": s["hand_error_mm"],
        "unreachable": s["unreachable"],
    }


def dial(cells: dict[str, dict[str, Any]]) -> tuple[list[str], list[dict[str, Any]]]:
    points = []
    lines = [
        "| setting | rotated replays failing | hand error (mm) | unreachable | base N(0, I) | "
        + " | ".join(f"{v} gain" for v in LABELS.values())
        + " |",
        "|---|---:|---:|---:|---:|" + "---:|" * len(LABELS),
    ]
    for name in PARTS["dial"]:
        d = cells[name]
        b = d["breaking"]
        row = [d["cell"].label]
        row += (
            [f"{b['replay_failure']:.3f}", f"{b['hand_error_mm']:.2f}", f"{b['unreachable']:.3f}"] if b else ["-"] * 3
        )
        row.append(format_mean_se(_control_rates(d, 1.0), count=True))
        row += [format_mean_se(gains(d, m), count=True) for m in LABELS]
        lines.append("| " + " | ".join(row) + " |")
        points.append({"cell": d["cell"], "breaking": b, "gains": {m: gains(d, m) for m in LABELS}})
    return lines + [""], points


def _verdict(xs: list[float]) -> str:
    """``up`` / ``down`` where the mean is more than two standard errors from 0 (at least 3
    values), ``none`` otherwise, ``-`` without enough values."""
    m, se = mean_se(xs)
    if len(xs) < 3 or math.isnan(se):
        return "-"
    return "up" if m - 2 * se > 0 else "down" if m + 2 * se < 0 else "none"


def _read(xs: list[float]) -> str:
    """``xs`` as mean +- s.e. (seeds) with its :func:`_verdict` where there are enough seeds."""
    v = _verdict(xs)
    return format_mean_se(xs, count=True) + ("" if v == "-" else f" {v}")


def _paired(data: dict[str, Any], a: str, b: str) -> list[float]:
    """Method ``a``'s final success minus ``b``'s, per seed that both have run."""
    fa = {r["seed"]: r["figures"]["final"] for r in data["runs"].get(a, [])}
    fb = {r["seed"]: r["figures"]["final"] for r in data["runs"].get(b, [])}
    return [fa[k] - fb[k] for k in sorted(fa.keys() & fb.keys())]


def claims(cells: dict[str, dict[str, Any]]) -> list[str]:
    """The evidence for each of the paper's three claims, with the rule that reads it. A
    difference counts when its mean is more than two standard errors (over seeds, at least 3)
    from 0; anything less is reported as no clear difference."""
    lines = [
        "Rule: a gain or a difference counts when its mean over seeds is more than two standard errors from 0 "
        "(at least 3 seeds); *up* / *down* / *none* below, *-* where there are too few seeds.",
        "",
        "**1. Steering improves the EDP** (final success minus the base's, paired by seed)",
        "",
        "| task | " + " | ".join(f"{v} gain" for v in LABELS.values()) + " | reading |",
        "|---|" + "---:|" * len(LABELS) + "---|",
    ]
    for name in PARTS["table1"]:
        d = cells[name]
        g = {m: gains(d, m) for m in LABELS}
        v = {m: _verdict(g[m]) for m in LABELS}
        up = [LABELS[m] for m in LABELS if v[m] == "up"]
        down = [LABELS[m] for m in LABELS if v[m] == "down"]
        if all(x == "-" for x in v.values()):
            reading = "too few seeds yet" if any(g.values()) else "not run yet"
        elif up:
            reading = "improved by " + ", ".join(up) + (" (worse: " + ", ".join(down) + ")" if down else "")
        else:
            reading = "no method improves it" + (" (worse: " + ", ".join(down) + ")" if down else "")
        lines.append(
            f"| {TASK_LABELS[d['cell'].task]} | " + " | ".join(_read(g[m]) for m in LABELS) + f" | {reading} |"
        )
    lines += [
        "",
        "The paper's metric, the peak, read the same way: each run's peak minus the peak its base alone would "
        "show over as many evaluations (the *base's own peak* of Table 1), paired by seed.",
        "",
        "| task | " + " | ".join(f"{v} peak excess" for v in LABELS.values()) + " |",
        "|---|" + "---:|" * len(LABELS),
    ]
    for name in PARTS["table1"]:
        d = cells[name]
        lines.append(
            f"| {TASK_LABELS[d['cell'].task]} | " + " | ".join(_read(peak_excess(d, m)) for m in LABELS) + " |"
        )
    lines += [
        "",
        "**2. Invariant critics avoid DSRL's Q divergence.** The latent reward is never positive (success - 1 per "
        "primitive step), so a mean Q above 0 is an overestimate: the table counts the runs whose mean Q rose above 0 "
        "at any evaluation once training had started, with the highest mean Q and the final one (mean +- s.e. over "
        "seeds). The paper ties the divergence to a high update-to-data ratio: the UTD-30 rows run Lift at its 30; "
        "the last rows run Lift on DSRL's own protocol (training episodes to the horizon, a critic over the noise, "
        "target entropy 0), with the Rust agents and with SB3 + escnn.",
        "",
        "| setting | method | runs above 0 | highest mean Q | final mean Q |",
        "|---|---|---:|---:|---:|",
    ]
    for name in (*PARTS["table1"], *PARTS["critic"][1:], *PARTS["sb3"]):
        d = cells[name]
        for m, label in LABELS.items():
            rs = d["runs"].get(m, [])
            if not rs:
                continue
            qs = [r["trained_q"] for r in rs if r["trained_q"]]
            if not qs:
                continue
            above = sum(1 for q in qs if max(q) > 0)
            lines.append(
                f"| {d['cell'].label} | {label} | {above} of {len(qs)} | "
                f"{format_mean_se([max(q) for q in qs], 1, count=True)} | "
                f"{format_mean_se([q[-1] for q in qs], 1, count=True)} |"
            )
    lines += [
        "",
        "**3. Strict equivariance pays where the task is symmetric and is a liability where joint limits break the "
        "symmetry; approximate equivariance adapts.** Equi-DSRL's final success minus Approx-Equi-DSRL's, paired by "
        "seed: the limits ablation, the controller ablation, then the dial from its most broken setting (its "
        "measure: the share of rotated expert demos that fail when replayed).",
        "",
        "| setting | rotated replays failing | Equi - Approx (final) | reading | Equi gain | Approx gain |",
        "|---|---:|---:|---|---:|---:|",
    ]
    for name in (*PARTS["limits"], *PARTS["controller"][1:], *PARTS["dial"]):
        d = cells[name]
        b = None if d["breaking"] is None else d["breaking"]["replay_failure"]
        diff = _paired(d, "equi", "approx")
        lines.append(
            f"| {d['cell'].label} | {'-' if b is None else f'{b:.3f}'} | {format_mean_se(diff, count=True)} | "
            f"{_verdict(diff)} | "
            f"{format_mean_se(gains(d, 'equi'), count=True)} | {format_mean_se(gains(d, 'approx'), count=True)} |"
        )
    return lines + [""]


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


COLOURS = {"dsrl": "tab:blue", "equi": "tab:orange", "approx": "tab:green"}


def curves_figure(cells: dict[str, dict[str, Any]], column: str, ylabel: str, path: Path) -> None:
    """One panel per Table 1 task: mean over seeds of ``column`` against env steps, shaded s.e.;
    the base policy as a dashed line (success only); the legend below the panels."""
    import numpy as np

    plt = _plt()
    names = PARTS["table1"]
    fig, axes = plt.subplots(1, len(names), figsize=(4.2 * len(names), 3.4), squeeze=False)
    for ax, name in zip(axes[0], names):
        d = cells[name]
        for m, label in LABELS.items():
            rs = d["runs"].get(m, [])
            if not rs:
                continue
            n = min(len(r["log"]) for r in rs)
            x = np.array([float(row["env_steps"]) for row in rs[0]["log"][:n]])
            ys = np.array([[float(row[column]) for row in r["log"][:n]] for r in rs])
            mean = ys.mean(axis=0)
            ax.plot(x, mean, color=COLOURS[m], label=f"{label} ({len(rs)} seeds)")
            if len(rs) > 1:
                se = ys.std(axis=0, ddof=1) / math.sqrt(len(rs))
                ax.fill_between(x, mean - se, mean + se, color=COLOURS[m], alpha=0.2, lw=0)
        base = _control_rates(d, 1.0)
        if column == "success_rate" and base:
            ax.axhline(mean_se(base)[0], color="k", ls="--", lw=1, label="base policy")
        ax.set_title(f"{TASK_LABELS[d['cell'].task]}")
        ax.set_xlabel("env steps")
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel(ylabel)
    handles, labels = {}, {}
    for ax in axes[0]:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            handles.setdefault(lab.split(" (")[0], h)
            labels.setdefault(lab.split(" (")[0], lab.split(" (")[0])
    if handles:
        fig.legend(handles.values(), labels.values(), loc="lower center", ncol=len(handles), frameon=False)
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _setting(cell: Cell) -> str:
    return "no limits" if cell.dial == math.inf else f"x {cell.dial:g}"


def dial_figure(points: list[dict[str, Any]], path: Path) -> None:
    """Left: the measured breaking at each setting of the dial. Right: each method's steering
    gain (mean +- s.e. over seeds) against that breaking, one marker per setting."""
    plt = _plt()
    fig, (left, right) = plt.subplots(1, 2, figsize=(10.5, 4.0))
    labels = [_setting(p["cell"]) for p in points]
    measured = [p for p in points if p["breaking"] is not None]
    xs = range(len(points))
    for key, name, marker in (
        ("replay_failure", "rotated expert demos that fail", "o"),
        ("unreachable", "rotated states out of reach", "s"),
    ):
        left.plot(
            [i for i, p in zip(xs, points) if p["breaking"]],
            [p["breaking"][key] for p in measured],
            marker=marker,
            label=name,
        )
    left.set_xticks(list(xs), labels)
    left.set_xlabel("joint ranges (the dial)")
    left.set_ylabel("share of rotated cases")
    left.set_title("Measured symmetry breaking")
    left.legend(frameon=False, fontsize=8)
    left.grid(alpha=0.3)
    for k, (m, label) in enumerate(LABELS.items()):
        pts = []
        for p in measured:
            mean, se = mean_se(p["gains"][m])
            if not math.isnan(mean):
                pts.append((p["breaking"]["replay_failure"], mean, 0.0 if math.isnan(se) else se, _setting(p["cell"])))
        pts.sort()
        if pts:
            offset = (k - 1) * 0.003  # side by side where settings measure alike
            right.errorbar(
                [x + offset for x, *_ in pts],
                [y for _, y, *_ in pts],
                yerr=[e for *_, e, _ in pts],
                color=COLOURS[m],
                marker="o",
                ls=":",
                capsize=3,
                label=label,
            )
            if k == 0:
                for x, y, _, name in pts:
                    right.annotate(name, (x, y), xytext=(4, 6), textcoords="offset points", fontsize=7)
    right.axhline(0.0, color="k", lw=0.8)
    right.set_xlabel("breaking: share of rotated expert demos that fail")
    right.set_ylabel("steering gain (final - base, same seeds)")
    right.set_title("Steering gain against the breaking")
    right.grid(alpha=0.3)
    handles, names = right.get_legend_handles_labels()
    if handles:
        fig.legend(handles, names, loc="lower center", ncol=3, frameon=False)
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def cost(cells: dict[str, dict[str, Any]], root: Path) -> list[str]:
    lines = [
        "| cell | method | runs | env steps | seconds per run (collect / train / evaluate) | minutes per run |",
        "|---|---|---:|---:|---|---:|",
    ]
    for name, d in cells.items():
        for m, rs in d["runs"].items():
            done = [r["summary"] for r in rs if r["summary"]]
            if not done:
                continue
            by = [s["seconds_by_activity"] for s in done if s.get("seconds_by_activity")]
            # the SB3 runner's clock is not split by activity
            activities = ("rollout", "train", "eval")
            parts = " / ".join(f"{sum(b.get(k, 0.0) for b in by) / len(by):.0f}" for k in activities) if by else "-"
            minutes = sum(s["seconds"] for s in done) / len(done) / 60
            lines.append(f"| {name} | {m} | {len(done)} | {done[0]['env_steps']:,} | {parts} | {minutes:.1f} |")
    lines += [
        "",
        "Each run's own clock (`summary.json`), one thread per run: a core-minute on a quiet core, more where "
        "the machine was shared (two trials per 2 cores, other jobs beside them).",
    ]
    return lines + [""]


def cost_summary(root: Path) -> list[str]:
    """What the whole study costs: core-hours done and left (``plan``'s estimate) and the wall
    time of its invocations so far."""
    b = budget(list(CELLS.values()), root)
    left = sum(x["core_h_left"] for x in b)
    done = sum(x["runs"] * x["core_h_per_run"] for x in b) - left
    runs, finished = sum(x["runs"] for x in b), sum(x["done"] for x in b)
    record = root / "study.json"
    r = json.loads(record.read_text()) if record.exists() else {"invocations": []}
    return [
        f"The whole study: {runs} runs, about {done + left:.1f} core-hours; "
        f"{finished} runs finished, about {done:.1f} core-hours done, about {left:.1f} core-hours left "
        "(`python -m equigym.study plan`, per cell). Wall time of its invocations so far on this machine: "
        f"{r.get('wall_seconds', 0) / 3600:.2f} h ({len(r['invocations'])} invocations).",
    ]


def _body(cells: dict[str, dict[str, Any]], dial_lines: list[str], figures: str, h: str, root: Path) -> list[str]:
    """Table 1, its figures, the ablations, the dial and the claims' evidence (the report's
    body and the docs block alike; ``figures``: the figures' directory as the reader sees it,
    ``h``: the sections' heading level)."""
    return [
        *cost_summary(root),
        "",
        f"{h} Table 1",
        "",
        *table1(cells),
        f"![success against env steps, one panel per task]({figures}success.png)",
        "",
        f"![mean Q against env steps, one panel per task]({figures}mean_q.png)",
        "",
        f"{h} Ablations",
        "",
        *comparison(
            cells,
            PARTS["controller"],
            "Controller and joint limits (Lift): a scene that commutes with rotations against the shipped one",
        ),
        *comparison(
            cells, PARTS["limits"], "Joint limits on Stack D1, each with an EDP trained on its own setting's demos"
        ),
        *comparison(cells, PARTS["sb3"], "SB3 + escnn cross-check on Lift, both agents on DSRL's own protocol"),
        *comparison(
            cells, PARTS["critic"], "The update-to-data ratio (Lift): the cpu preset's 4 against the paper's 30"
        ),
        f"{h} The symmetry-breaking dial",
        "",
        *dial_lines,
        f"![steering gain against the measured symmetry breaking]({figures}dial.png)",
        "",
        f"{h} The paper's claims: the evidence",
        "",
        *claims(cells),
    ]


def write(root: Path, update_docs: bool = False) -> str:
    cells = {name: load_cell(CELLS[name], root) for name in CELLS}
    for d in cells.values():
        d["breaking"] = breaking_of(root, d["cell"])
    dial_lines, points = dial(cells)
    text = [
        "# The study: Table 1, ablations, symmetry-breaking dial",
        "",
        "Generated by `python -m equigym.study report` from the files under this directory "
        "(module docs of `equigym.study` and `equigym.study.report` for the protocol).",
        "",
        *_body(cells, dial_lines, "", "##", root),
        "## Cost",
        "",
        *cost(cells, root),
    ]
    root.mkdir(parents=True, exist_ok=True)
    report = "\n".join(text)
    (root / "report.md").write_text(report)
    curves_figure(cells, "success_rate", "success rate", root / "success.png")
    curves_figure(cells, "mean_q", "mean Q of sampled replay batches", root / "mean_q.png")
    dial_figure(points, root / "dial.png")
    if update_docs:
        figures = os.path.relpath(root, ROOT / "docs") + "/"
        # README: the peak and the final tables (each: title, blank, header, rule, one row per task, blank)
        summary = "\n".join(table1(cells)[: 2 * (5 + len(PARTS["table1"]))]).rstrip()
        _replace_block(
            ROOT / "docs/steering.md", "study", "\n".join(_body(cells, dial_lines, figures, "####", root)).rstrip()
        )
        _replace_block(ROOT / "README.md", "study-summary", summary)
    return report


def _replace_block(path: Path, marker: str, body: str) -> None:
    begin, end = f"<!-- {marker}:begin -->", f"<!-- {marker}:end -->"
    text = path.read_text()
    if begin not in text or end not in text:
        raise SystemExit(f"{path} has no {begin} ... {end} block")
    head, rest = text.split(begin, 1)
    _, tail = rest.split(end, 1)
    path.write_text(f"{head}{begin}\n{body}\n{end}{tail}")
