"""Turn steering logs (runs/steer/<task>/<method>/seed<k>/log.csv) into the paper's Table 1
(peak success, mean +- standard error over seeds, next to the base policy's success) and plots
of success rate and mean Q against environment steps."""

from __future__ import annotations

import csv
import json
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path

import numpy as np

from equigym.steer.runs import run_summary
from equigym.steer.stats import format_mean_se

LABELS = {
    "dsrl": "DSRL",
    "equi": "Equi-DSRL",
    "approx": "Approx-Equi-DSRL",
    "sac": "SAC (raw actions)",
    # Runs of the Rust agents (equigym.steer; run.json says "agent": "rust").
    "rust-dsrl": "DSRL (Rust)",
    "rust-equi": "Equi-DSRL (Rust)",
    "rust-approx": "Approx-Equi-DSRL (Rust)",
}


def _roots(root: str | Path | list[str | Path]) -> list[Path]:
    return [Path(r) for r in root] if isinstance(root, (list, tuple)) else [Path(root)]


def load_runs(root: str | Path | list[str | Path]) -> dict[tuple[str, str], list[dict]]:
    """Runs under one or more roots, keyed by (task folder, method); Rust agents' methods are
    prefixed ``rust-`` so that they sit beside the SB3 runs of the same method."""
    runs: dict[tuple[str, str], list[dict]] = defaultdict(list)
    for base_dir in _roots(root):
        for log in sorted(base_dir.glob("*/*/seed*/log.csv")):
            meta = json.loads((log.parent / "run.json").read_text())
            with open(log) as f:
                rows = [{k: float(v) for k, v in r.items()} for r in csv.DictReader(f)]
            method = f"rust-{meta['method']}" if meta.get("agent") == "rust" else meta["method"]
            if rows:
                runs[(log.parents[2].name, method)].append(
                    {"meta": meta, "rows": rows, "summary": run_summary(log.parent) or None}
                )
    return runs


def load_base(root: str | Path | list[str | Path]) -> dict[str, float]:
    """Base-policy success per task folder (``<root>/<task>/base.json``, from ``steer base``/``sweep``)."""
    return {
        p.parent.name: float(json.loads(p.read_text())["success_rate"])
        for d in _roots(root)
        for p in sorted(d.glob("*/base.json"))
    }


def _cost_table(runs: dict, tasks: list[str], methods: list[str], labels: dict[str, str]) -> list[str]:
    """Where the runs' time went, from the Rust runs' ``summary.json`` (``seconds_by_activity``,
    ``eval_env_steps``): mean wall seconds per run by activity (one run per core), and the
    evaluation's seconds per primitive env step (its physics, with one DDIM call per chunk)."""
    rows = []
    for t in tasks:
        for m in methods:
            sums = [r["summary"] for r in runs.get((t, m), []) if r["summary"] and r["summary"].get("eval_env_steps")]
            if not sums:
                continue
            act = {k: float(np.mean([x["seconds_by_activity"][k] for x in sums])) for k in ("rollout", "train", "eval")}
            total = sum(act.values())
            eval_steps = float(np.mean([x["eval_env_steps"] for x in sums]))
            ms_per_step = (
                1000 * sum(x["seconds_by_activity"]["eval"] for x in sums) / sum(x["eval_env_steps"] for x in sums)
            )
            rows.append(
                f"| {t} | {labels[m]} | {len(sums)} | {act['rollout']:.0f} | {act['train']:.0f} | {act['eval']:.0f} "
                f"| {eval_steps:,.0f} | {ms_per_step:.2f} | {total / 60:.1f} |"
            )
    if not rows:
        return []
    return [
        "",
        "Where a run's time went (Rust runs, `summary.json`; mean over the runs, wall seconds of one "
        "run on one core, so other load on the machine shows here):",
        "",
        "| task | method | runs | collecting (s) | gradient steps (s) | evaluating (s) | evaluation env steps "
        "| evaluation ms per env step | minutes per run (one thread) |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|",
        *rows,
    ]


def _task_table(
    tasks: list[str], columns: list[str], lead: dict[str, Callable[[str], str]], cell: Callable[[str, int], str]
) -> list[str]:
    """A markdown table, one row per task: the ``lead`` columns (header -> cell of a task), then
    one column per header in ``columns`` (cell of a task and the column's index)."""
    lines = [
        "| task | " + "".join(f"{h} | " for h in lead) + " | ".join(columns) + " |",
        "|---|" + "---:|" * (len(lead) + len(columns)),
    ]
    for t in tasks:
        lines.append(
            f"| {t} | "
            + "".join(f"{f(t)} | " for f in lead.values())
            + " | ".join(cell(t, i) for i in range(len(columns)))
            + " |"
        )
    return lines


def write_report(root: str | Path | list[str | Path], out: str | Path, base: dict[str, float] | None = None) -> str:
    runs = load_runs(root)
    base = {**load_base(root), **(base or {})}
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    tasks = sorted({t for t, _ in runs})
    methods = [m for m in LABELS if any(m == mm for _, mm in runs)]
    # Beside Rust runs, the SB3 runs say so too.
    both = any(m.startswith("rust-") for m in methods) and any(not m.startswith("rust-") for m in methods)
    labels = {m: f"{LABELS[m]} (SB3)" if both and not m.startswith("rust-") else LABELS[m] for m in methods}
    lines = [
        "# Steering results",
        "",
        f"From `{', '.join(str(r) for r in _roots(root))}` by `equigym.steer.sweep_report` (`python -m equigym.steer report` or `python -m baselines.steer report`). Success rates of the "
        "stochastic steering policy, each evaluation >= 50 episodes unless the runs said otherwise; mean +- standard "
        "error over seeds. The base policy column is the EDP alone (latent noise N(0, I), 100 episodes).",
        "",
    ]

    def cell(values: list[float]) -> str:
        return format_mean_se(values, 3)

    # Peak over evaluations is the paper's Table 1 metric; with few noisy evaluations it is biased
    # upwards, so the mean of each run's last two evaluations is reported beside it.
    for title, stat in (
        ("Peak success (the paper's Table 1 metric)", lambda rates: max(rates)),
        ("Final success (mean of the last two evaluations)", lambda rates: float(np.mean(rates[-2:]))),
    ):

        def success(t: str, m: str, stat=stat) -> str:
            rs = runs.get((t, m), [])
            if not rs:
                return "-"
            steps = int(min(run["rows"][-1]["env_steps"] for run in rs))
            rates = cell([stat([r["success_rate"] for r in run["rows"]]) for run in rs])
            return f"{rates} ({len(rs)} seed{'s' if len(rs) != 1 else ''}, {steps:,} steps)"

        def base_cell(t: str) -> str:
            b = base.get(t)
            return "-" if b is None else f"{b:.3f}"

        lines += [f"**{title}**", ""]
        lines += _task_table(
            tasks, [labels[m] for m in methods], {"base policy": base_cell}, lambda t, i: success(t, methods[i])
        )
        lines.append("")

    # Value divergence: rewards are in [-chunk, 0], so a sampled batch's mean Q above 0 comes
    # from the entropy bonus or from overestimation; report each method's largest and last value.
    def mean_q(t: str, i: int) -> str:
        qs = [[r["mean_q"] for r in run["rows"] if np.isfinite(r["mean_q"])] for run in runs.get((t, methods[i]), [])]
        qs = [q for q in qs if q]
        return f"{np.mean([max(q) for q in qs]):.1f} / {np.mean([q[-1] for q in qs]):.1f}" if qs else "-"

    lines += ["Mean Q of sampled replay batches (soft Q, entropy bonus included): largest / last, mean over seeds.", ""]
    lines += _task_table(tasks, [labels[m] for m in methods], {}, mean_q)
    lines += _cost_table(runs, tasks, methods, labels)
    text = "\n".join(lines) + "\n"
    (out / "table.md").write_text(text)
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:  # pragma: no cover
        return text
    for t in tasks:
        fig, axes = plt.subplots(1, 2, figsize=(11, 4))
        for m in methods:
            # Thin lines: seeds; thick line and band: mean +- standard error over the seeds that
            # reached each evaluation point (the paper's style).
            color = f"C{methods.index(m)}"
            by_step: dict[float, dict[str, list[float]]] = defaultdict(lambda: {"success_rate": [], "mean_q": []})
            for run in runs.get((t, m), []):
                x = [r["env_steps"] for r in run["rows"]]
                for ax, key in zip(axes, ("success_rate", "mean_q")):
                    ax.plot(x, [r[key] for r in run["rows"]], color=color, alpha=0.25, lw=0.8)
                for r in run["rows"]:
                    for key in ("success_rate", "mean_q"):
                        if np.isfinite(r[key]):
                            by_step[r["env_steps"]][key].append(r[key])
            xs = sorted(by_step)
            for ax, key in zip(axes, ("success_rate", "mean_q")):
                pts = [(x, by_step[x][key]) for x in xs if by_step[x][key]]
                if not pts:
                    continue
                px = np.array([p[0] for p in pts])
                mean = np.array([np.mean(p[1]) for p in pts])
                se = np.array([np.std(p[1], ddof=1) / np.sqrt(len(p[1])) if len(p[1]) > 1 else 0.0 for p in pts])
                ax.plot(px, mean, color=color, lw=2, label=labels[m] if key == "success_rate" else None)
                ax.fill_between(px, mean - se, mean + se, color=color, alpha=0.2)
        if t in base:
            axes[0].axhline(base[t], color="k", ls="--", lw=1, label="base policy")
        axes[0].set_ylabel("success rate")
        axes[1].set_ylabel("mean Q (sampled batch)")
        for ax in axes:
            ax.set_xlabel("environment steps")
            ax.grid(alpha=0.3)
        axes[0].legend()
        fig.suptitle(t)
        fig.tight_layout()
        fig.savefig(out / f"{t}.png", dpi=110)
        plt.close(fig)
    return text
