#!/usr/bin/env python3
"""A second, independent one-thread vector env for the suite's 2-core ceiling; run by
benches/suite.py with the project's python.

The suite steps its own one-thread vector env on the first CPU while this process steps the
same work (same reset seed, same actions) on the second, at the same moment. Their summed rate
over one of them alone is what two cores of this machine give two fully independent copies of
the workload: the ceiling a 2-thread pool could reach, with nothing shared between the copies
but the hardware (caches, memory, the host's scheduling of the two virtual CPUs).

Protocol, one line each way: ``load PATH SEED`` (an ``.npy`` of actions; reset with SEED,
untimed) is answered ``ready``; ``go`` steps every action and is answered with the wall seconds;
``quit`` ends the process.
"""
import sys

from _worker_common import pin


def main():
    env_id, b, cpu = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    pin(cpu)  # before the env exists: its pool's thread starts pinned

    import time

    import gymnasium
    import numpy as np

    import equigym  # noqa: F401  (registers the ids)

    env = gymnasium.make_vec(env_id, num_envs=b, threads=1)
    actions = None
    print("ready", flush=True)
    for line in sys.stdin:
        cmd = line.split()
        if not cmd or cmd[0] == "quit":
            break
        if cmd[0] == "load":
            actions = np.load(cmd[1])
            env.reset(seed=int(cmd[2]))
            print("ready", flush=True)
        elif cmd[0] == "go":
            t0 = time.perf_counter()
            for a in actions:
                env.step(a)
            print(f"{time.perf_counter() - t0:.9f}", flush=True)
    env.close()


if __name__ == "__main__":
    main()
