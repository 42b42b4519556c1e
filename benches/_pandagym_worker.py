#!/usr/bin/env python3
"""Time one panda-gym task; run by benches/suite.py with the panda-gym venv's python.

Prints one JSON line (the last line of stdout). Same method as the equigym and robosuite
sides: pinned to one CPU, seeded uniform-random actions drawn before timing, reset(seed) and
--warmup steps, then the median over --reps runs of --steps unwrapped env.step() calls (the
unwrapped env never asks for a reset), and the median of --resets resets.
"""
import json
import platform
import statistics
import time

from _worker_common import pin, timing_parser


def main():
    ap = timing_parser("Time one panda-gym task.")
    ap.add_argument("--env", default="PandaPickAndPlace-v3")
    args = ap.parse_args()
    affinity = pin(args.cpu)

    from importlib.metadata import version

    import gymnasium
    import numpy as np
    import panda_gym  # noqa: F401  (registers the ids)

    out = {"env": args.env, "affinity": affinity, "args": vars(args),
           "versions": {"panda-gym": version("panda-gym"), "pybullet": version("pybullet"),
                        "numpy": np.__version__, "python": platform.python_version()}}
    env = gymnasium.make(args.env).unwrapped
    sim = env.sim
    out["substeps"] = int(sim.n_substeps)
    out["control_dt"] = float(sim.timestep * sim.n_substeps)
    space = env.action_space
    space.seed(args.seed)
    env.reset(seed=args.seed)
    for _ in range(args.warmup):
        env.step(space.sample())
    rates = []
    for _ in range(args.reps):
        actions = [space.sample() for _ in range(args.steps)]
        t0 = time.perf_counter()
        for a in actions:
            env.step(a)
        rates.append(args.steps / (time.perf_counter() - t0))
    out["steps_per_s_runs"] = rates
    out["steps_per_s"] = statistics.median(rates)
    ts = []
    for i in range(args.resets):
        t0 = time.perf_counter()
        env.reset(seed=args.seed + i)
        ts.append(time.perf_counter() - t0)
    out["reset_ms"] = 1e3 * statistics.median(ts)
    env.close()
    print(json.dumps(out))


if __name__ == "__main__":
    main()
