"""The study's command line (what the study is: the docs of :mod:`equigym.study`).

python -m equigym.study plan [--parts table1 dial ...]          # the runs and what they cost
python -m equigym.study prepare --cell stack-nolimits           # an EDP the limits ablation needs
python -m equigym.study run [--parts ...] [--cells ...] [--out docs/steering/study] [--cpus 2] [--address HOST:PORT]
    [--hours H [--whole-runs]]
python -m equigym.study report [--out docs/steering/study] [--update-docs]
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from equigym.steer import METHODS
from equigym.study.cells import CELLS, PARTS, ROOT, cells_of, plan
from equigym.study.report import write
from equigym.study.runner import prepare, run, run_controls


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
        print(write(Path(a.out), update_docs=a.update_docs))
