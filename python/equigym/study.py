"""The paper's Table 1, its ablations and a symmetry-breaking dial, as one resumable study.

    python -m equigym.study plan [--parts table1 dial ...]          # the runs and what they cost
    python -m equigym.study prepare --cell stack-nolimits           # an EDP the limits ablation needs
    python -m equigym.study run [--parts ...] [--cells ...] [--out docs/steering/study] [--cpus 2] [--address HOST:PORT]
    python -m equigym.study report [--out docs/steering/study] [--update-docs]

A study is a set of *cells*: one environment setting with its EDP, run by the steering methods
over seeds at one budget (:data:`CELLS`). *Parts* name the cells each question needs
(:data:`PARTS`): ``table1`` (Lift, Stack D1, Square D2, the paper's table), ``sb3`` (the SB3 +
escnn cross-check on Lift), ``controller`` (a scene that commutes with rotations, the Cartesian
controller without joint limits, against the joint controller with them), ``limits`` (Stack D1
with and without joint limits, each with an EDP trained on demos of its own setting),
``critic`` (Lift at the paper's update-to-data ratio, 30, against the cpu preset's 4: the
paper ties DSRL's Q divergence to it) and ``dial`` (the joint-limit ranges scaled about their
midpoints, ``physics.joint_limit_scale``: the symmetry breaking measured at each setting beside
each method's steering gain). A cell
shared by two parts (Table 1's Lift is the dial's scale 1 and the controller ablation's joint
arm) is run once.

``run`` puts every (cell, method, seed) of the chosen parts into one Ray Tune experiment, seed
by seed so that early results cover every cell, one CPU per trial (``--address`` joins a
cluster whose nodes hold this checkout at the same path). Each trial advances its run one
evaluation interval at a time from the agent's own checkpoint (``equigym.steer``), so a study
that is stopped and started again (``Tuner.restore`` where the experiment's settings are
unchanged, a fresh experiment over the same run directories otherwise) loses at most one
interval per running trial and gives the same bits; ``--hours`` stops the trials between
intervals after that long (a session's budget), and the same command resumes them; with
``--whole-runs`` a run starts only where it can finish by then (for machines that do not keep
the runs' checkpoints until the next invocation, so that no CPU goes to progress that would be
lost; the cheaper trials after it fill the time). A study's
logs committed without ``tune/`` (Tune's own state, kept out of the repository) resume on
another machine at the run level: a fresh experiment over the same run directories, in which
finished runs return at once. Before the runs it measures the symmetry
breaking of every dial setting (:func:`equigym.symmetry.measure_breaking`); after them the
control arms of every cell (the base policy N(0, I), narrow-noise bases N(0, s^2 I), on the
runs' own evaluation starts and seeds; ``equigym.steer.controls``). Every file lies under
``--out``: ``runs/<cell>/...`` (each run's ``log.csv``, ``train.csv``, ``run.json``,
``summary.json``), ``runs/<cell>/controls.json``, ``breaking/<cell>.json``, ``study.json`` (each
invocation's wall time).

``report`` rebuilds every table and figure from those files alone: ``report.md`` (Table 1
beside the paper's, with controls and intervals; the ablations; the dial; what the study cost),
``success.png`` and ``mean_q.png`` (one panel per task), ``dial.png``; ``--update-docs`` also
rewrites the generated blocks of ``docs/steering.md`` and the README.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

from equigym.steer import (
    CONTROL_SCALES,
    METHODS,
    RECIPES,
    read_run,
    record_invocation,
    resume_steps,
    run_steps,
    run_summary,
    run_trial,
    tune_experiment,
)

#: The repository root: relative paths of cells (EDP files) are relative to it.
ROOT = Path(__file__).resolve().parents[2]
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
#: Lift recipe runs of docs/steering/arm3, the study's own Stack D1 and Square D2 runs with the
#: noise-aliased recipe, whose gradient steps decode the EDP; the SB3 figure is an estimate).
DEFAULT_COST = {("lift", "rust"): 0.020, ("stack", "rust"): 0.060, ("square", "rust"): 0.21, ("lift", "sb3"): 0.08}
#: For a cell with its own UTD and no finished run to measure: the share of a run's time spent
#: training at the cpu preset's UTD (the Lift runs' cost table in the report), scaled by the
#: ratio of the UTDs.
TRAIN_SHARE, PRESET_UTD = 0.8, 4
#: ``--whole-runs``: a run starts only where its cell's mean measured cost times this fits
#: before the deadline (a margin for runs slower than the mean: a run's clock depends on what
#: shares the machine).
WHOLE_RUN_MARGIN = 1.25
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
        Cell("square", "square", "Square D2", 32_000, 4_000),
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


def _run_dirs(cell: Cell, root: Path) -> list[Path]:
    return sorted(p.parent for p in cell.out(root).rglob("seed*/log.csv"))


def _cost_per_step(root: Path) -> dict[tuple[str, str, int | None], float]:
    """Core-seconds per env step by (task, agent, the cell's own UTD): the study's own finished
    runs where it has them (their clocks, one run per CPU), else :data:`DEFAULT_COST`."""
    seen: dict[tuple[str, str, int | None], list[float]] = {}
    for cell in CELLS.values():
        for d in _run_dirs(cell, root):
            summary = run_summary(d)
            if summary.get("env_steps"):
                key = (cell.task, cell.agent, cell.utd)
                seen.setdefault(key, []).append(summary["seconds"] / summary["env_steps"])
    return {**{(*k, None): v for k, v in DEFAULT_COST.items()}, **{k: sum(v) / len(v) for k, v in seen.items()}}


def _cell_cost(cost: dict[tuple[str, str, int | None], float], cell: Cell) -> float:
    """Core-seconds per env step of one of the cell's runs (:func:`_cost_per_step`); a UTD of
    its own with nothing measured yet scales the preset's training share."""
    key = (cell.task, cell.agent, cell.utd)
    if key in cost or cell.utd is None:
        return cost[key]
    return cost[(cell.task, cell.agent, None)] * (1 + TRAIN_SHARE * (cell.utd / PRESET_UTD - 1))


def budget(cells: list[Cell], root: Path) -> list[dict[str, Any]]:
    """Per cell: its runs, those finished, core-hours per run (measured where the study has
    finished runs of its kind, else estimated: :func:`_cost_per_step`) and core-hours left (the
    env steps its runs still lack, so a run part-way, or one whose budget grew, counts for what
    it has still to do from where it can resume on this machine)."""
    cost = _cost_per_step(root)
    out = []
    for cell in cells:
        # a finished run is done; a run part-way counts where it can resume (its checkpoint here)
        reached = [cell.steps if run_steps(d) >= cell.steps else resume_steps(d) for d in _run_dirs(cell, root)]
        runs = len(cell.methods) * len(cell.seeds)
        per_step = _cell_cost(cost, cell) / 3600
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


def _trial_config(cell: Cell, job: dict[str, Any], root: Path) -> dict[str, Any]:
    """What ``equigym.steer.run_trial`` takes for one job of ``cell``."""
    return {
        "agent": cell.agent,
        "method": job["method"],
        "task": cell.task,
        "seed": job["seed"],
        "steps": cell.steps,
        "out": str(cell.out(root)),
        "preset": "cpu",
        "env": cell.env,
        "eval_every": cell.eval_every,
        "eval_episodes": cell.eval_episodes,
        "policy": cell.policy_path(),
        "ent_init": None,
        **RECIPES[cell.recipe],
        **({"utd": cell.utd} if cell.utd is not None else {}),
    }


def measure_dial(cells: list[Cell], root: Path, episodes: int) -> None:
    """The symmetry breaking of every dial cell's setting (``breaking/<cell>.json``), measured
    once: the expert's transition-invariance errors and its rotated demonstrations replayed."""
    from equigym.symmetry import measure_breaking

    for cell in cells:
        path = root / "breaking" / f"{cell.name}.json"
        if cell.dial is None or path.exists():
            continue
        t0 = time.perf_counter()
        report = measure_breaking(cell.task, episodes=episodes, **cell.env)
        report["seconds"] = time.perf_counter() - t0
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(report, indent=1) + "\n")
        print(f"breaking of {cell.name}: {time.perf_counter() - t0:.0f} s")


def run_controls(cells: list[Cell], root: Path, threads: int) -> None:
    """The control arms of every cell with runs, on the runs' own starts and seeds (cached in
    ``runs/<cell>/controls.json``; a seed is added when its first run is)."""
    from equigym.steer import controls

    for cell in cells:
        dirs = _run_dirs(cell, root)
        if not dirs:
            continue
        metas = [json.loads((d / "run.json").read_text()) for d in dirs]
        seeds = sorted({int(m["seed"]) for m in metas})
        controls(read_run(dirs[0])["meta"], seeds, CONTROL_SCALES, cell.out(root) / "controls.json", threads)


def run(a: argparse.Namespace) -> None:
    try:
        from ray import tune
    except ImportError as e:  # pragma: no cover
        raise SystemExit("the study needs Ray Tune: pip install 'equigym[sweep]' (or 'ray[tune]')") from e
    root = Path(a.out).resolve()
    os.chdir(ROOT)  # EDP paths are relative to the checkout, in the runs' records too
    cells = cells_of(a.parts, a.methods, a.quick, a.cells)
    missing = [c for c in cells if not (ROOT / c.policy_path()).exists()]
    if missing:
        raise SystemExit(
            "no EDP file for "
            + ", ".join(f"{c.name} ({c.policy_path()})" for c in missing)
            + ": python -m equigym.study prepare --cell NAME"
        )
    root.mkdir(parents=True, exist_ok=True)
    started = time.time()
    record = root / "study.json"
    record_invocation(
        record, {"started": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "parts": a.parts, "cpus": a.cpus}, start=True
    )
    measure_dial(cells, root, 2 if a.quick else a.breaking_episodes)
    by_name = {c.name: c for c in cells}
    space = {"job": tune.grid_search(jobs(cells))}
    name = "study-" + "-".join(sorted(a.parts))
    name += "".join("-" + "-".join(sorted(x)) for x in (a.methods, a.cells) if x)
    settings = json.dumps([asdict(c) for c in cells], sort_keys=True, default=str)
    settings_file = root / "tune" / f"{name}.settings.json"
    storage = root / "tune"

    deadline = started + 3600 * a.hours if a.hours else None
    cost = _cost_per_step(root)
    # seconds per env step of each cell's runs, with a margin, for trials that must not start
    # what they cannot finish by the deadline
    per_step = {c.name: _cell_cost(cost, c) * WHOLE_RUN_MARGIN for c in cells} if a.whole_runs else {}

    def trainable(config: dict[str, Any]) -> None:
        os.chdir(ROOT)  # EDP paths are relative to the checkout; runs record them so
        job = config["job"]
        c = {**_trial_config(by_name[job["cell"]], job, root), "deadline": deadline}
        run_trial({**c, "cost_per_step": per_step.get(job["cell"])})

    def settings_written(restored: bool) -> None:
        if not restored:
            settings_file.write_text(settings)

    storage.mkdir(parents=True, exist_ok=True)
    same = settings_file.exists() and settings_file.read_text() == settings
    results, _ = tune_experiment(
        trainable,
        space,
        name,
        storage,
        address=a.address,
        cpus=a.cpus,
        restore=same,
        pythonpath=True,
        before_fit=settings_written,
    )
    paused = [r for r in results if r.error is not None and "Paused" in repr(r.error)]
    deferred = [r for r in paused if "not started" in repr(r.error)]  # --whole-runs: would not finish
    failed = [r for r in results if r.error is not None and r not in paused]
    run_controls(cells, root, a.cpus or 1)
    wall = time.time() - started
    entry = {"wall_seconds": round(wall, 1), "trials": len(results), "paused": len(paused), "failed": len(failed)}
    entry |= {"not_started": len(deferred)} if a.whole_runs else {}
    record_invocation(record, entry, start=False)
    print(
        f"{len(results)} trials, {len(paused) - len(deferred)} paused at the deadline, {len(deferred)} not started "
        f"(would not finish by it), {len(failed)} failed, {wall:.0f} s wall"
    )
    if failed:
        raise SystemExit(f"{len(failed)} trials failed; run the same command again to resume")


def prepare(name: str) -> None:
    """Make the EDP file a cell needs (:data:`PREPARE`), with the commands in the checkout."""
    if name not in PREPARE:
        raise SystemExit(f"cells that need preparing: {sorted(PREPARE)}")
    for args in PREPARE[name]:
        print("+ python " + " ".join(args), flush=True)
        subprocess.run([sys.executable, *args], check=True, cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)})


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(
        prog="python -m equigym.study", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    sub = p.add_subparsers(dest="cmd", required=True)
    for name in ("plan", "run", "report"):
        s = sub.add_parser(name)
        s.add_argument("--out", default="docs/steering/study")
        if name != "report":
            s.add_argument("--parts", nargs="+", choices=sorted(PARTS), default=list(PARTS))
            s.add_argument("--cpus", type=int, default=os.cpu_count() or 1, help="local Ray CPUs; one per trial")
            s.add_argument("--methods", nargs="+", choices=METHODS, default=None, help="only these methods' runs")
            s.add_argument("--cells", nargs="+", choices=sorted(CELLS), default=None, help="only these cells' runs")
            s.add_argument("--quick", action="store_true", help="a smoke test of the pipeline (tiny budgets)")
    r = sub.choices["run"]
    r.add_argument("--address", default=None, help="join a Ray cluster (its nodes hold this checkout at this path)")
    r.add_argument("--breaking-episodes", type=int, default=40, help="expert episodes per dial breaking measure")
    r.add_argument(
        "--hours",
        type=float,
        default=None,
        help="stop the trials between evaluation intervals after this long, then evaluate the controls; "
        "the same command resumes them",
    )
    r.add_argument(
        "--whole-runs",
        action="store_true",
        help="with --hours: start a run only where it can finish before the deadline (its cell's measured cost), "
        "for machines that do not keep the runs' checkpoints until the next invocation",
    )
    c = sub.add_parser("controls", help="evaluate the control arms of the runs there are (run does it at its end)")
    c.add_argument("--out", default="docs/steering/study")
    c.add_argument("--cpus", type=int, default=os.cpu_count() or 1, help="evaluation threads")
    sub.choices["report"].add_argument("--update-docs", action="store_true", help="rewrite the generated doc blocks")
    pr = sub.add_parser("prepare")
    pr.add_argument("--cell", required=True)
    a = p.parse_args(argv)
    if a.cmd == "plan":
        print(plan(cells_of(a.parts, a.methods, a.quick, a.cells), Path(a.out), a.cpus))
    elif a.cmd == "run":
        if a.whole_runs and not a.hours:
            p.error("--whole-runs needs --hours (the deadline the runs must finish by)")
        run(a)
    elif a.cmd == "prepare":
        prepare(a.cell)
    elif a.cmd == "controls":
        root = Path(a.out).resolve()
        os.chdir(ROOT)
        run_controls(list(CELLS.values()), root, a.cpus)
    else:
        from equigym.study_report import write

        print(write(Path(a.out), update_docs=a.update_docs))


if __name__ == "__main__":
    main()
