"""What the peer workers share: the timing options and the CPU pin. Each worker runs with its
own peer's venv python, from this directory, so this module uses the standard library only."""

from __future__ import annotations

import argparse
import os


def timing_parser(description: str) -> argparse.ArgumentParser:
    """An argument parser with the options every worker times by: steps per run, runs (the
    median is reported), warm-up steps, resets timed, the seed and the CPU to pin to."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--warmup", type=int, default=200)
    ap.add_argument("--resets", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cpu", type=int, default=0)
    return ap


def pin(cpu: int) -> list[int] | None:
    """Pin this process to one CPU; the CPUs it then may run on, or None where it cannot pin."""
    try:
        os.sched_setaffinity(0, {cpu})
        return sorted(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # not Linux, or cpu not allowed
        return None
