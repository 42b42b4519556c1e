#!/usr/bin/env python3
"""Time one robosuite task; run by benches/peers.py with the robosuite venv's python.

Prints exactly one JSON line (the last line of stdout) so the parent can parse it even
though robosuite prints warnings on import.

Method (same as shared/bench/peers/bench_robosuite.py, so numbers are comparable with
RESULTS.md): Panda, default composite controller (OSC_POSE arm), control_freq=20,
no renderer/cameras, ignore_done=True so no resets fall inside step timing, uniform
random actions over the action box generated before timing, median of reps.
"""
import json
import os
import platform
import statistics
import sys
import time

from _worker_common import pin, timing_parser

# Nothing renders; this only keeps robosuite/mujoco from probing for GLFW.
os.environ.setdefault("MUJOCO_GL", "egl")


def median_rate(n, seconds):
    return statistics.median(n / s for s in seconds)


def main():
    ap = timing_parser("Time one robosuite task.")
    ap.add_argument("--task", required=True)
    ap.add_argument("--no-physics", action="store_true", help="skip the raw mj_step replay")
    args = ap.parse_args()
    affinity = pin(args.cpu)

    import mujoco
    import numpy as np
    import robosuite

    out = {
        "task": args.task, "affinity": affinity, "args": vars(args),
        "versions": {"robosuite": robosuite.__version__, "mujoco": mujoco.__version__,
                     "numpy": np.__version__, "python": platform.python_version()},
    }
    t0 = time.perf_counter()
    env = robosuite.make(args.task, robots="Panda", has_renderer=False, has_offscreen_renderer=False,
                         use_camera_obs=False, control_freq=20, seed=args.seed, ignore_done=True)
    out["make_s"] = time.perf_counter() - t0
    low, high = env.action_spec
    rng = np.random.default_rng(args.seed)
    out["action_dim"] = len(low)
    out["substeps"] = int(round(env.control_timestep / env.model_timestep))

    env.reset()
    for a in rng.uniform(low, high, size=(args.warmup, len(low))):
        env.step(a)

    secs = []
    for _ in range(args.reps):
        acts = rng.uniform(low, high, size=(args.steps, len(low)))
        env.reset()
        t0 = time.perf_counter()
        for a in acts:
            env.step(a)
        secs.append(time.perf_counter() - t0)
    out["steps_per_s_runs"] = [args.steps / s for s in secs]
    out["steps_per_s"] = median_rate(args.steps, secs)

    # Reset cost: robosuite's default hard_reset=True rebuilds the model from XML each time;
    # hard_reset=False is the fair comparison for an env that resets in place.
    for hard in (True, False):
        env.hard_reset = hard
        ts = []
        for _ in range(args.resets):
            t0 = time.perf_counter()
            env.reset()
            ts.append(time.perf_counter() - t0)
        out["reset_ms_hard" if hard else "reset_ms_soft"] = 1e3 * statistics.median(ts)

    if not args.no_physics:
        out.update(physics_only(env, rng, low, high, min(args.steps, 1000), args.reps))
    env.close()
    print(json.dumps(out), flush=True)


def physics_only(env, rng, low, high, nrec, reps):
    """Physics ceiling: replay the ctrl that robosuite's controller wrote at every substep
    through bare mujoco.mj_step on a fresh MjData, so no Python controller/obs cost is left."""
    import mujoco
    import numpy as np

    env.reset()
    m, d = env.sim.model._model, env.sim.data._data
    spec = mujoco.mjtState.mjSTATE_INTEGRATION
    state0 = np.empty(mujoco.mj_stateSize(m, spec))
    mujoco.mj_getState(m, d, state0, spec)

    # lite_physics (default) steps via step1/step2; otherwise via step. Record ctrl at either.
    ctrls, sim = [], env.sim
    orig = {"step2": sim.step2, "step": sim.step}

    def recorder(f):
        def w(*a, **k):
            ctrls.append(d.ctrl.copy())
            return f(*a, **k)
        return w

    sim.step2, sim.step = recorder(orig["step2"]), recorder(orig["step"])
    try:
        for a in rng.uniform(low, high, size=(nrec, len(low))):
            env.step(a)
    finally:
        sim.step2, sim.step = orig["step2"], orig["step"]
    ctrls = np.asarray(ctrls)

    d0 = mujoco.MjData(m)
    secs = []
    for _ in range(reps):
        mujoco.mj_setState(m, d0, state0, spec)
        mujoco.mj_forward(m, d0)
        t0 = time.perf_counter()
        for c in ctrls:
            d0.ctrl[:] = c
            mujoco.mj_step(m, d0)
        secs.append(time.perf_counter() - t0)
    mj_rate = median_rate(len(ctrls), secs)
    substeps = len(ctrls) / nrec
    return {"mj_step_per_s": mj_rate, "mj_substeps_per_env_step": substeps,
            "physics_only_steps_per_s": mj_rate / substeps}


if __name__ == "__main__":
    sys.exit(main())
