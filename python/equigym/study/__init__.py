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

The package: :mod:`~equigym.study.cells` (the cells, parts and costs), :mod:`~equigym.study.runner`
(the experiment), :mod:`~equigym.study.report` (the tables and figures) and
:mod:`~equigym.study.cli` (the command line).
"""

from equigym.study.cells import (
    ABLATION_SEEDS,
    CELLS,
    DEFAULT_COST,
    LABELS,
    LIFT_STEPS,
    PAPER,
    PARTS,
    PREPARE,
    RECIPE,
    ROOT,
    SEEDS,
    TASK_LABELS,
    Cell,
    budget,
    cell_cost,
    cells_of,
    cost_per_step,
    jobs,
    plan,
    run_dirs,
)
from equigym.study.cli import main
from equigym.study.runner import (
    WHOLE_RUN_MARGIN,
    measure_dial,
    prepare,
    run,
    run_controls,
    trial_config,
)

__all__ = [
    "ABLATION_SEEDS",
    "CELLS",
    "DEFAULT_COST",
    "LABELS",
    "LIFT_STEPS",
    "PAPER",
    "PARTS",
    "PREPARE",
    "RECIPE",
    "ROOT",
    "SEEDS",
    "TASK_LABELS",
    "WHOLE_RUN_MARGIN",
    "Cell",
    "budget",
    "cell_cost",
    "cells_of",
    "cost_per_step",
    "jobs",
    "main",
    "measure_dial",
    "plan",
    "prepare",
    "run",
    "run_controls",
    "run_dirs",
    "trial_config",
]
