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

The package has one module per concern: :mod:`~equigym.steer.runs` (one run, the run options and
recipes, and the readers of a run directory), :mod:`~equigym.steer.trials` (the runs as Ray
Tune trials: sweep, screen, and the experiment plumbing the study shares),
:mod:`~equigym.steer.analysis` (headline figures, diagnostics and the comparison with the control
arms) and :mod:`~equigym.steer.cli` (the command line). Their public names are re-exported
here.
"""

from equigym.steer.analysis import (
    CONTROL_SCALES,
    FINAL_EVALUATIONS,
    compare,
    controls,
    diagnose,
    mean_se,
    report,
    summarize,
    trained_rows,
)
from equigym.steer.cli import add_run_arguments, main
from equigym.steer.runs import (
    CHECKPOINTS,
    DEFAULT_EVAL,
    METHODS,
    RECIPES,
    RUN_OPTIONS,
    TASKS,
    read_run,
    resume_steps,
    run,
    run_env,
    run_steps,
    run_summary,
)
from equigym.steer.trials import (
    Paused,
    config_label,
    parse_grid,
    record_invocation,
    run_clocks,
    run_trial,
    screen,
    screen_table,
    sweep,
    sweep_jobs,
    tune_experiment,
)

__all__ = [
    "CHECKPOINTS",
    "CONTROL_SCALES",
    "DEFAULT_EVAL",
    "FINAL_EVALUATIONS",
    "METHODS",
    "RECIPES",
    "RUN_OPTIONS",
    "TASKS",
    "Paused",
    "add_run_arguments",
    "compare",
    "config_label",
    "controls",
    "diagnose",
    "main",
    "mean_se",
    "parse_grid",
    "read_run",
    "resume_steps",
    "record_invocation",
    "report",
    "run",
    "run_clocks",
    "run_env",
    "run_steps",
    "run_summary",
    "run_trial",
    "screen",
    "screen_table",
    "summarize",
    "sweep",
    "sweep_jobs",
    "trained_rows",
    "tune_experiment",
]
