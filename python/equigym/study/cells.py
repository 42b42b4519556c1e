"""The study's cells (one environment setting with its EDP, run by the methods over seeds at one
budget), the parts that name them, and what they cost: the plan that the runner and the report
share.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from equigym.steer import METHODS, UNNAMED_EDP_KERNEL, resume_steps, run_steps, run_summary

#: The repository root: relative paths of cells (EDP files) are relative to it.
ROOT = Path(__file__).resolve().parents[3]
#: The steering recipe every cell runs unless it names another (docs/steering.md: the steering
#: issue's outcome: an action-space critic, training episodes ending at success, an entropy
#: target within the actor's reach).
RECIPE = "na-tos-h20"
#: The paper's Table 1 (maximum evaluation success), for the report.
PAPER = {
    "lift": {"base": 0.617, "dsrl": 0.808, "equi": 0.840, "approx": 0.820},
    "stack": {"base": 0.568, "dsrl": 0.740, "equi": 0.728, "approx": 0.800},
    "square": {"base": 0.275, "dsrl": 0.552, "equi": 0.644, "approx": 0.604},
}
LABELS = {"dsrl": "DSRL", "equi": "Equi-DSRL", "approx": "Approx-Equi-DSRL"}
TASK_LABELS = {"lift": "Lift", "stack": "Stack D1", "square": "Square D2"}
#: Core-seconds per primitive env step of one run, where the study has no run of the cell's
#: task and agent to measure it from (measured, one run per core, evaluations included: the
#: Lift recipe runs of docs/steering/arm3, the study's own Stack D1 runs with the noise-aliased
#: recipe, whose gradient steps decode the EDP; Square D2 on the Fourier kernel from an 8k-step
#: run of the recipe, its 4,000 gradient steps at 0.038 s against the dense kernel's 0.24 in the
#: study's first Square runs, with training extrapolated to 32k; the SB3 figure is an estimate).
DEFAULT_COST = {("lift", "rust"): 0.020, ("stack", "rust"): 0.060, ("square", "rust"): 0.05, ("lift", "sb3"): 0.08}
#: For a cell with its own UTD and no finished run to measure: the share of a run's time spent
#: training at the cpu preset's UTD (the Lift runs' cost table in the report), scaled by the
#: ratio of the UTDs.
TRAIN_SHARE, PRESET_UTD = 0.8, 4

#: Lift's budget, for every Lift cell that is compared with Table 1's (the controller ablation
#: and the dial share its runs): at 16k Equi-DSRL's success was still rising (the report's
#: "still moving?" column, 5 seeds), so the runs go on to 32k, one evaluation every 2k.
LIFT_STEPS = 32_000
#: Seeds of the paper's table, and of the cheaper ablations.
SEEDS = (0, 1, 2, 3, 4)
ABLATION_SEEDS = (0, 1, 2)


@dataclass(frozen=True)
class Cell:
    """One environment setting and EDP, steered by ``methods`` over ``seeds``."""

    name: str
    task: str
    label: str
    steps: int
    eval_every: int
    seeds: tuple[int, ...] = SEEDS
    methods: tuple[str, ...] = METHODS
    eval_episodes: int = 50
    env: dict[str, Any] = field(default_factory=dict)
    #: The EDP file, relative to the repository root (default: the task's shipped one).
    policy: str | None = None
    agent: str = "rust"
    recipe: str = RECIPE
    #: The dial's setting (joint-limit scale; ``inf`` for no limits), for dial cells.
    dial: float | None = None
    #: Gradient steps per transition where the cell sets its own (default: the preset's).
    utd: int | None = None
    #: How the EDP's regular-to-regular layers run (``equigym.steer.EDP_KERNELS``; the runs and
    #: their control arms alike): dense unless a cell names another, since the cells were begun
    #: before the Fourier kernel became the runtime's default.
    edp_kernel: str = UNNAMED_EDP_KERNEL

    def policy_path(self) -> str:
        return self.policy or f"assets/edp/{self.task}.safetensors"

    def out(self, root: Path) -> Path:
        return root / "runs" / self.name


def _scaled(scale: float, seeds: tuple[int, ...] = ABLATION_SEEDS) -> Cell:
    return Cell(
        f"lift-scale{scale:g}",
        "lift",
        f"Lift, joint ranges x {scale:g}",
        LIFT_STEPS,
        2_000,
        seeds=seeds,
        env={"physics": {"joint_limit_scale": scale}},
        dial=scale,
    )


#: Every cell of the study. Budgets: Lift :data:`LIFT_STEPS`; Stack's and Square's episodes are
#: longer, so 32k with an evaluation every 4k. The cross-checks that ask their own question keep
#: 16k: the SB3 one (DSRL's protocol, both agents alike) and UTD 30 (whether the critics diverge;
#: at 16k it already takes 7.5x the gradient steps of a 16k run at UTD 4).
CELLS: dict[str, Cell] = {
    c.name: c
    for c in (
        Cell("lift", "lift", "Lift", LIFT_STEPS, 2_000, dial=1.0),
        Cell("stack", "stack", "Stack D1", 32_000, 4_000),
        # Square D2's EDP (hidden width 1024) decodes 5x faster on the Fourier kernel, and its
        # decodes are most of a run; no Square run had finished on the dense one.
        Cell("square", "square", "Square D2", 32_000, 4_000, edp_kernel="fourier"),
        # The SB3 + escnn agents know DSRL's own protocol only: the cross-check runs it on both.
        Cell("lift-dsrl", "lift", "Lift, Rust, DSRL's protocol", 16_000, 2_000, seeds=ABLATION_SEEDS, recipe="dsrl"),
        Cell(
            "lift-sb3",
            "lift",
            "Lift, SB3 + escnn, DSRL's protocol",
            16_000,
            2_000,
            seeds=ABLATION_SEEDS,
            agent="sb3",
            recipe="dsrl",
        ),
        Cell(
            "lift-cartesian-nolimits",
            "lift",
            "Lift, Cartesian controller, no joint limits",
            LIFT_STEPS,
            2_000,
            seeds=ABLATION_SEEDS,
            env={"controller": "cartesian", "joint_limits": False},
        ),
        Cell(
            "stack-nolimits",
            "stack",
            "Stack D1, no joint limits (EDP from limit-free demos)",
            32_000,
            4_000,
            seeds=ABLATION_SEEDS,
            env={"joint_limits": False},
            policy="docs/steering/study/edp/stack-nolimits.safetensors",
        ),
        # The paper ties DSRL's Q divergence to its update-to-data ratio (30); the cpu preset's 4
        # does not provoke it (claim 2).
        Cell("lift-utd30", "lift", "Lift, UTD 30 (the paper's)", 16_000, 2_000, seeds=ABLATION_SEEDS, utd=30),
        _scaled(0.6),
        _scaled(0.8),
        _scaled(1.25),
        Cell(
            "lift-nolimits",
            "lift",
            "Lift, no joint limits",
            LIFT_STEPS,
            2_000,
            seeds=ABLATION_SEEDS,
            env={"joint_limits": False},
            dial=math.inf,
        ),
    )
}
PARTS: dict[str, tuple[str, ...]] = {
    "table1": ("lift", "stack", "square"),
    "sb3": ("lift-dsrl", "lift-sb3"),
    "controller": ("lift", "lift-cartesian-nolimits"),
    "limits": ("stack", "stack-nolimits"),
    "critic": ("lift", "lift-utd30"),
    "dial": ("lift-scale0.6", "lift-scale0.8", "lift", "lift-scale1.25", "lift-nolimits"),
}
#: How the limits ablation's EDP is made: the shipped Stack recipe (docs/edp.md, "Stack D1") on
#: demos recorded without joint limits.
PREPARE = {
    "stack-nolimits": [
        [
            "-m", "equigym.demos", "--task", "stack", "--variant", "D1", "--episodes", "100",
            "--execution-noise", "0.005", "--env", '{"joint_limits": false}',
            "--out", "data/stack_d1_100_dart005_nolimits.hdf5",
        ],
        [
            "-m", "baselines.edp", "train", "--demos", "data/stack_d1_100_dart005_nolimits.hdf5",
            "--out", "docs/steering/study/edp/stack-nolimits.safetensors", "--steps", "40000",
            "--hidden-fields", "64", "--seed", "0",
        ],
    ]
}  # fmt: skip


def cells_of(
    parts: list[str], methods: list[str] | None = None, quick: bool = False, only: list[str] | None = None
) -> list[Cell]:
    """The cells the parts need, each once, in the order the parts name them; with ``methods``
    only those methods' runs, with ``only`` only those cells (e.g. to finish one cell before
    the others); ``quick``: the pipeline's smoke test (seed 0, 64 env steps, 2-episode
    evaluations every 32), to check a set-up before paying for the study."""
    names: list[str] = []
    for p in parts:
        names += [n for n in PARTS[p] if n not in names and (not only or n in only)]
    cells = [CELLS[n] for n in names]
    if methods:
        cells = [replace(c, methods=tuple(m for m in c.methods if m in methods)) for c in cells]
    if quick:
        cells = [replace(c, steps=64, eval_every=32, eval_episodes=2, seeds=c.seeds[:1]) for c in cells]
    return [c for c in cells if c.methods]


def jobs(cells: list[Cell]) -> list[dict[str, Any]]:
    """Every (cell, method, seed), seed-major, so that early results cover every cell."""
    seeds = sorted({s for c in cells for s in c.seeds})
    return [{"cell": c.name, "method": m, "seed": s} for s in seeds for c in cells for m in c.methods if s in c.seeds]


def run_dirs(cell: Cell, root: Path) -> list[Path]:
    return sorted(p.parent for p in cell.out(root).rglob("seed*/log.csv"))


def cost_per_step(root: Path) -> dict[tuple[str, str, int | None], float]:
    """Core-seconds per env step by (task, agent, the cell's own UTD): the study's own finished
    runs where it has them (their clocks, one run per CPU; only runs on the cell's EDP kernel),
    else :data:`DEFAULT_COST`."""
    seen: dict[tuple[str, str, int | None], list[float]] = {}
    for cell in CELLS.values():
        for d in run_dirs(cell, root):
            summary = run_summary(d)
            meta = json.loads((d / "run.json").read_text()) if (d / "run.json").exists() else {}
            if summary.get("env_steps") and meta.get("edp_kernel", UNNAMED_EDP_KERNEL) == cell.edp_kernel:
                key = (cell.task, cell.agent, cell.utd)
                seen.setdefault(key, []).append(summary["seconds"] / summary["env_steps"])
    return {**{(*k, None): v for k, v in DEFAULT_COST.items()}, **{k: sum(v) / len(v) for k, v in seen.items()}}


def cell_cost(cost: dict[tuple[str, str, int | None], float], cell: Cell) -> float:
    """Core-seconds per env step of one of the cell's runs (:func:`cost_per_step`); a UTD of
    its own with nothing measured yet scales the preset's training share."""
    key = (cell.task, cell.agent, cell.utd)
    if key in cost or cell.utd is None:
        return cost[key]
    return cost[(cell.task, cell.agent, None)] * (1 + TRAIN_SHARE * (cell.utd / PRESET_UTD - 1))


def budget(cells: list[Cell], root: Path) -> list[dict[str, Any]]:
    """Per cell: its runs, those finished, core-hours per run (measured where the study has
    finished runs of its kind, else estimated: :func:`cost_per_step`) and core-hours left (the
    env steps its runs still lack, so a run part-way, or one whose budget grew, counts for what
    it has still to do from where it can resume on this machine)."""
    cost = cost_per_step(root)
    out = []
    for cell in cells:
        # a finished run is done; a run part-way counts where it can resume (its checkpoint here)
        reached = [cell.steps if run_steps(d) >= cell.steps else resume_steps(d) for d in run_dirs(cell, root)]
        runs = len(cell.methods) * len(cell.seeds)
        per_step = cell_cost(cost, cell) / 3600
        out.append(
            {
                "cell": cell,
                "runs": runs,
                "done": sum(1 for s in reached if s >= cell.steps),
                "core_h_per_run": cell.steps * per_step,
                "core_h_left": (runs * cell.steps - sum(reached)) * per_step,
            }
        )
    return out


def plan(cells: list[Cell], root: Path, cpus: int) -> str:
    """The runs the cells need, what is done, and the core-hours left."""
    lines = [
        "| cell | task | setting | methods x seeds | env steps | done | core-h left |",
        "|---|---|---|---:|---:|---:|---:|",
    ]
    total_left = 0.0
    for b in budget(cells, root):
        cell, n, done = b["cell"], b["runs"], b["done"]
        left = b["core_h_left"]
        total_left += left
        setting = (
            " ".join([json.dumps(cell.env)] * bool(cell.env) + [f"UTD {cell.utd}"] * (cell.utd is not None)) or "-"
        )
        lines.append(
            f"| {cell.name} | {cell.task} | {setting} | {len(cell.methods)} x {len(cell.seeds)} | "
            f"{cell.steps:,} | {done}/{n} | {left:.1f} |"
        )
    lines.append("")
    lines.append(f"Left: {total_left:.1f} core-hours, about {total_left / cpus:.1f} h on {cpus} CPUs.")
    return "\n".join(lines)
