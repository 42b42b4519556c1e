"""Running the study: its cells' (method, seed) jobs as one resumable Ray Tune experiment, the
dial's breaking measures before them and the control arms after them, and the EDPs some cells
need first (``prepare``).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

from equigym.steer import CONTROL_SCALES, RECIPES, read_run, record_invocation, run_trial, tune_experiment
from equigym.study.cells import (
    PREPARE,
    ROOT,
    Cell,
    cell_cost,
    cells_of,
    cost_per_step,
    jobs,
    run_dirs,
)

#: ``--whole-runs``: a run starts only where its cell's mean measured cost times this fits
#: before the deadline (a margin for runs slower than the mean: a run's clock depends on what
#: shares the machine).
WHOLE_RUN_MARGIN = 1.25


def trial_config(cell: Cell, job: dict[str, Any], root: Path) -> dict[str, Any]:
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
        "edp_kernel": cell.edp_kernel,
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
        dirs = run_dirs(cell, root)
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
    cost = cost_per_step(root)
    # seconds per env step of each cell's runs, with a margin, for trials that must not start
    # what they cannot finish by the deadline
    per_step = {c.name: cell_cost(cost, c) * WHOLE_RUN_MARGIN for c in cells} if a.whole_runs else {}

    def trainable(config: dict[str, Any]) -> None:
        os.chdir(ROOT)  # EDP paths are relative to the checkout; runs record them so
        job = config["job"]
        c = {**trial_config(by_name[job["cell"]], job, root), "deadline": deadline}
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
