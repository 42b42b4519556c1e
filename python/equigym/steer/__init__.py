"""Steering agents in Rust (DSRL, Equi-DSRL, Approx-Equi-DSRL): one run, a sweep on Ray Tune,
and a report next to the SB3 baselines; the command line is ``python -m equigym.steer``
(:mod:`~equigym.steer.cli`, whose docs list its commands).

The package has one module per concern: :mod:`~equigym.steer.runs` (one run, the run options and
recipes, and the readers of a run directory), :mod:`~equigym.steer.trials` (the runs as Ray
Tune trials: sweep, screen, and the experiment plumbing the study shares),
:mod:`~equigym.steer.analysis` (headline figures, diagnostics and the comparison with the control
arms), :mod:`~equigym.steer.sweep_report` (a sweep's Table 1 and plots, SB3 runs beside them),
:mod:`~equigym.steer.stats` (mean +- s.e. and Wilson intervals, as numbers and as table text)
and :mod:`~equigym.steer.cli` (the command line). Their public names are re-exported here.
"""

from equigym.steer.analysis import (
    CONTROL_SCALES,
    FINAL_EVALUATIONS,
    compare,
    controls,
    diagnose,
    report,
    summarize,
    trained_rows,
)
from equigym.steer.cli import add_run_arguments, main
from equigym.steer.runs import (
    CHECKPOINTS,
    DEFAULT_EVAL,
    EDP_KERNELS,
    METHODS,
    RECIPES,
    RUN_OPTIONS,
    TASKS,
    UNNAMED_EDP_KERNEL,
    read_run,
    resume_steps,
    run,
    run_env,
    run_steps,
    run_summary,
)
from equigym.steer.stats import format_mean_se, format_pooled, mean_se
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
    "EDP_KERNELS",
    "FINAL_EVALUATIONS",
    "METHODS",
    "RECIPES",
    "RUN_OPTIONS",
    "TASKS",
    "UNNAMED_EDP_KERNEL",
    "Paused",
    "add_run_arguments",
    "compare",
    "config_label",
    "controls",
    "diagnose",
    "format_mean_se",
    "format_pooled",
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
