#!/usr/bin/env python3
"""The performance suite: equigym and its peers measured side by side in one run.

    .venv/bin/python benches/suite.py            # full run (~5 min on 2 cores), writes benches/results/suite.*
    .venv/bin/python benches/suite.py --quick    # smoke test (~1 min)
    bash benches/setup_peers.sh                  # once: the robosuite and panda-gym venvs

Measures, taking turns (never two measurements at once):

1. single environment, one core (every process pinned to --cpu): control steps/s and reset time
   of each equigym task vs robosuite on the same task (plus robosuite's physics-only MuJoCo rate:
   its recorded controls replayed through bare mj_step) and panda-gym's PandaPickAndPlace-v3;
2. the native vector env (gymnasium.make_vec) for B in --batch-sizes on 1 and 2 threads
   (pinned to the first T CPUs): env steps/s, time per batched step, and the share of each step
   spent in Python (wall time of EquiVectorEnv.step minus the time inside the Rust batch step,
   which the core measures with the GIL released); vector reset time; and, from B = 16, the
   machine's own 2-core ceiling: the one-thread env beside an independent copy of itself in
   another process on the second CPU (``_vector_worker.py``), both stepping the same work at
   once, their summed rate over the one-thread rate (what two cores here give work that shares
   nothing but the hardware; on a virtual machine whose two CPUs slow each other it is below 2);
3. the latent-action vector env (``gymnasium.make_vec("EquiLift-Latent-v0")``: one batched DDIM
   of the shipped EDP + the chunks' env steps per call) for B in --latent-batch-sizes on 1 and 2
   threads, and the EDP's chunks/s in Rust vs the same MLP + DDIM in PyTorch (needs torch).

Writes Markdown + JSON (--out, default benches/results/suite.md) and a PNG plot next to them,
with the machine, the load average before/after every part, and the ratios of the targets.
"""
import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse
import datetime
import json
import shlex
import statistics
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(1, str(HERE.parent))  # baselines.edp, for the PyTorch side of the EDP timing
import peers  # noqa: E402  (shared helpers: pinning, load, versions, the equigym and robosuite timers)

PEERS_DIR = peers.PEERS_DIR
PANDAGYM_WORKER = HERE / "_pandagym_worker.py"
TASKS = {"EquiLift-v0": "lift", "EquiStack-v0": "stack", "EquiSquare-v0": "square"}
# Targets of the performance issue (ratios measured in the same run).
TARGET_VS_ROBOSUITE = 20.0
# The fast-arm targets: Lift at least 1.2x MuJoCo's bare physics step on one core (the floor),
# 3x the goal; the vector env at least 1.9x faster on 2 threads than on 1 from B = 16 on.
FLOOR_VS_PHYSICS_ONLY = 1.2
TARGET_VS_PHYSICS_ONLY = 3.0
TARGET_THREAD_SCALING = 1.9
SCALING_MIN_BATCH = 16
TARGET_PYTHON_SHARE = 0.10


def parse_args():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--equigym-ids", nargs="+", default=list(TASKS))
    ap.add_argument("--steps", type=int, default=2000, help="single-env steps per repetition")
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--warmup", type=int, default=200)
    ap.add_argument("--resets", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cpu", type=int, default=0)
    ap.add_argument("--batch-sizes", default="1,2,4,8,16,32,64")
    ap.add_argument("--threads", default="1,2")
    ap.add_argument("--vector-task", default="EquiLift-v0")
    ap.add_argument("--latent-batch-sizes", default="1,16,64")
    ap.add_argument("--latent-steps", type=int, default=1500, help="latent steps per repetition (all sub-envs)")
    ap.add_argument("--no-latent", action="store_true", help="skip the latent-action env and EDP part")
    ap.add_argument("--vector-reps", type=int, default=5,
                    help="repetitions of each (B, T), the thread counts alternating (the scaling is their median ratio)")
    ap.add_argument("--vector-env-steps", type=int, default=4000,
                    help="environment steps per repetition of each (B, T) (at least 20 batch steps)")
    ap.add_argument("--robosuite-python", type=Path, default=PEERS_DIR / "venv_robosuite" / "bin" / "python")
    ap.add_argument("--pandagym-python", type=Path, default=PEERS_DIR / "venv_pandagym" / "bin" / "python")
    ap.add_argument("--no-peers", action="store_true", help="equigym only")
    ap.add_argument("--quick", action="store_true", help="smoke test: fewer steps, B in 1,8,64")
    ap.add_argument("--timeout", type=float, default=1800)
    ap.add_argument("--out", type=Path, default=HERE / "results" / "suite.md")
    ap.add_argument("--update-docs", "--update-readme", dest="update_docs", action="store_true",
                    help="also rewrite the figures between the suite markers in docs/performance.md")
    ap.add_argument("--from-json", type=Path,
                    help="measure nothing: rewrite the report, plot (and docs/performance.md) from a suite JSON file")
    args = ap.parse_args()
    if args.quick:
        args.steps, args.reps, args.resets, args.warmup = 300, 1, 3, 50
        args.vector_env_steps = 640
        args.vector_reps = 2
        args.batch_sizes = "1,8,64"
        args.latent_steps = 200
    args.latent_batch_sizes = [int(b) for b in str(args.latent_batch_sizes).split(",")]
    args.batch_sizes = [int(b) for b in str(args.batch_sizes).split(",")]
    args.threads = [int(t) for t in str(args.threads).split(",")]
    args.equigym_ids = [i for s in args.equigym_ids for i in s.split(",") if i]
    return args


def log(msg):
    print(msg, file=sys.stderr, flush=True)


# ---------------------------------------------------------------- peers (subprocesses)

def bench_pandagym(args):
    return peers.run_worker(args.pandagym_python, PANDAGYM_WORKER, [], args)


#: The CPUs this process may use, read before any part of the suite pins it to fewer.
ALL_CPUS = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []


def bench_vector(env_id, b, threads, args):
    """The vector env at batch size ``b`` for every thread count in ``threads``, the counts'
    repetitions alternating (T=1, T=2, T=1, ...) so that drift in the machine's speed falls on
    all of them alike; each T's pool is started pinned to the first T CPUs, and the main thread
    is pinned the same way for its repetitions. Within a repetition every T does the same work:
    the same reset seed (untimed) and the same actions, and since the thread count moves no bits,
    the same trajectories (random actions with auto-reset otherwise give each T its own mix of
    contacts and resets, a workload difference the paired ratio would read as scaling). Returns
    one result per T; each T > 1 also gets ``scaling_runs`` (its rate over T=1's in the same
    repetition) and ``scaling`` (their median)."""
    import gymnasium

    cpus = ALL_CPUS
    n = max(20, args.vector_env_steps // b)
    envs, res = {}, {}
    for t in threads:
        pin_first(cpus, t)
        r = res[t] = {"B": b, "threads": t, "load_before": peers.loadavg(), "affinity": cpus[:t]}
        t0 = time.perf_counter()
        envs[t] = gymnasium.make_vec(env_id, num_envs=b, threads=t)  # the pool starts here, on the pinned CPUs
        r["make_s"] = time.perf_counter() - t0
        envs[t].action_space.seed(args.seed)
        rs = []
        for i in range(max(3, args.resets // 2)):
            r0 = time.perf_counter()
            envs[t].reset(seed=args.seed + i)
            rs.append(time.perf_counter() - r0)
        r["reset_ms"] = 1e3 * statistics.median(rs)
        for a in [envs[t].action_space.sample() for _ in range(max(5, n // 10))]:
            envs[t].step(a)
    runs = {t: {"rate": [], "step_us": [], "rust_us": [], "py_share": [], "cpu_us": []} for t in threads}
    measure_ceiling = b >= SCALING_MIN_BATCH and threads[0] == 1 and len(cpus) >= 2
    pair = _CeilingPair(env_id, b, cpus, envs[threads[0]]) if measure_ceiling else None
    pair_rates = []
    if pair:
        pair.run([envs[threads[0]].action_space.sample() for _ in range(max(5, n // 10))], args.seed)  # warm-up
    for rep in range(args.vector_reps):
        actions = [envs[threads[0]].action_space.sample() for _ in range(n)]
        for t in threads:
            pin_first(cpus, t)
            core = envs[t].unwrapped.core
            envs[t].reset(seed=args.seed + 1000 + rep)
            core.stepping_seconds = 0.0
            c0 = time.process_time()  # CPU time of every thread of the process, load-independent
            t0 = time.perf_counter()
            for a in actions:
                envs[t].step(a)
            wall = time.perf_counter() - t0
            rust = core.stepping_seconds
            k = runs[t]
            k["cpu_us"].append(1e6 * (time.process_time() - c0) / (n * b))
            k["rate"].append(n * b / wall)
            k["step_us"].append(1e6 * wall / n)
            k["rust_us"].append(1e6 * rust / n)
            k["py_share"].append((wall - rust) / wall)
        if pair:
            pair_rates.append(pair.run(actions, args.seed + 1000 + rep))
    if pair:
        pair.close()
        one = runs[threads[0]]["rate"]
        ceiling = [x / y for x, y in zip(pair_rates, one)]
        res[threads[0]].update(pair_steps_per_s_runs=pair_rates, ceiling_runs=ceiling, ceiling=statistics.median(ceiling))
    for t in threads:
        k, r = runs[t], res[t]
        i = k["rate"].index(statistics.median_low(k["rate"]))  # report the median run's numbers together
        r.update(batch_steps=n, env_steps_per_s=k["rate"][i], env_steps_per_s_runs=k["rate"], step_us=k["step_us"][i],
                 cpu_us_per_env_step=k["cpu_us"][i], rust_step_us=k["rust_us"][i],
                 python_us=k["step_us"][i] - k["rust_us"][i], python_share=k["py_share"][i])
        if t != threads[0]:
            pairs = [x / y for x, y in zip(k["rate"], runs[threads[0]]["rate"])]
            r.update(scaling_runs=pairs, scaling=statistics.median(pairs))
        envs[t].close()
    pin_first(cpus, len(cpus))
    return [res[t] for t in threads]


class _CeilingPair:
    """The machine's own 2-core ceiling for the vector env at one batch size: the suite's
    one-thread env on the first CPU and an independent one-thread copy in another process
    (``_vector_worker.py``) on the second, stepping the same work at the same moment. Their
    summed rate over the one-thread rate alone is what two cores give two copies that share
    nothing but the hardware, so a 2-thread pool's T=2 / T=1 can be read against it."""

    def __init__(self, env_id, b, cpus, env):
        import subprocess
        import tempfile

        self.env, self.b, self.cpus = env, b, cpus
        self.tmp = Path(tempfile.mkdtemp(prefix="equigym-ceiling-")) / "actions.npy"
        self.proc = subprocess.Popen([sys.executable, str(HERE / "_vector_worker.py"), env_id, str(b), str(cpus[1])],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=HERE)
        self._expect("ready")

    def _expect(self, word):
        line = self.proc.stdout.readline().strip()
        if line != word:
            raise RuntimeError(f"vector worker: expected {word!r}, got {line!r}")

    def run(self, actions, seed):
        """Both copies step ``actions`` from ``seed``'s reset at once; their summed env steps/s."""
        import numpy as np

        np.save(self.tmp, np.stack(actions))
        self.proc.stdin.write(f"load {self.tmp} {seed}\n")
        self.proc.stdin.flush()
        pin_first(self.cpus, 1)
        self.env.reset(seed=seed)
        self._expect("ready")
        self.proc.stdin.write("go\n")
        self.proc.stdin.flush()
        t0 = time.perf_counter()
        for a in actions:
            self.env.step(a)
        wall = time.perf_counter() - t0
        other = float(self.proc.stdout.readline())
        work = len(actions) * self.b
        return work / wall + work / other

    def close(self):
        self.proc.stdin.write("quit\n")
        self.proc.stdin.flush()
        self.proc.wait(timeout=60)
        self.tmp.unlink(missing_ok=True)
        self.tmp.parent.rmdir()


# ---------------------------------------------------------------- latent-action env and EDP

def bench_latent(b, t, args):
    import gymnasium
    import numpy as np

    res = {"B": b, "threads": t, "load_before": peers.loadavg()}
    envs = gymnasium.make_vec("EquiLift-Latent-v0", num_envs=b, threads=t)
    core = envs.unwrapped.core
    n = max(10, args.latent_steps // b)
    rng = np.random.default_rng(args.seed)
    envs.reset(seed=args.seed)
    for _ in range(3):
        envs.step(rng.standard_normal((b, 40)))
    rates, py_share, cpu_used = [], [], []
    for _ in range(args.reps):
        latents = [rng.standard_normal((b, 40)) for _ in range(n)]
        core.stepping_seconds = 0.0
        c0, t0 = time.process_time(), time.perf_counter()
        for w in latents:
            envs.step(w)
        wall = time.perf_counter() - t0
        rates.append(n * b / wall)
        py_share.append((wall - core.stepping_seconds) / wall)
        cpu_used.append((time.process_time() - c0) / wall)
    k = rates.index(statistics.median(rates))
    res.update(latent_steps_per_s=rates[k], env_steps_per_s=rates[k] * envs.unwrapped.chunk_len,
               python_share=py_share[k], cpus_used=cpu_used[k])
    envs.close()
    return res


def bench_edp(args):
    import equigym.latent
    from baselines.edp import benchmark

    return {"rows": benchmark(equigym.latent.shipped_policy("lift"), batches=(1, 16, 256), seconds=1.0 if args.quick else 2.0)}


# ---------------------------------------------------------------- report

#: The PyTorch float32 column of ``baselines.edp.benchmark``'s rows (``baselines.edp.BENCH_TORCH32``,
#: restated because the report reads the results file without importing torch and escnn).
TORCH32_COLUMN = "pytorch (float32)"


def rust_chunks(row):
    """The Rust runtime's chunks/s in a row of ``baselines.edp.benchmark``: its first column, the
    runtime's default kernel (the committed suite.json's rows name it by their build's label)."""
    return next(v for k, v in row.items() if k != "batch")


def fmt(x, spec=",.0f"):
    return "–" if x is None else format(x, spec)


def get(res, key):
    return None if not res or "error" in res else res.get(key)


def cpus_used(v):
    """Average number of CPUs the process kept busy during the timed steps (CPU time / wall time)."""
    c, w, b = get(v, "cpu_us_per_env_step"), get(v, "step_us"), get(v, "B")
    return c * b / w if c and w and b else None


def ratio(a, b, spec=".1f"):
    return f"{a / b:{spec}}×" if a and b else "–"


def scaling(by, b):
    """T=2 over T=1 at batch size b: the median of the alternating repetitions' ratios (runs of
    the suite before they alternated: the ratio of the two medians)."""
    v1, v2 = by.get((b, 1)), by.get((b, 2))
    if get(v2, "scaling") is not None:
        return get(v2, "scaling")
    r1, r2 = get(v1, "env_steps_per_s"), get(v2, "env_steps_per_s")
    return r2 / r1 if r1 and r2 else None


def times(x, spec=".2f"):
    return f"{x:{spec}}×" if x else "–"


def latent_section(m, latent, edp):
    L = ["", "## Latent-action env (EquiLift-Latent-v0, shipped EDP, `gymnasium.make_vec`)", ""]
    if not latent:
        return L + ["(not measured in this run)"]
    L += ["One latent step = one deterministic DDIM (5 steps) of the batch's B latent noises + 4 control steps per "
          "sub-env. *Python share* as above.", "",
          "| B | threads | latent steps/s | env steps/s | Python share | CPUs used |", "|---:|---:|---:|---:|---:|---:|"]
    for v in latent:
        L.append(f"| {v['B']} | {v['threads']} | {fmt(get(v, 'latent_steps_per_s'))} | {fmt(get(v, 'env_steps_per_s'))} "
                 f"| {fmt(100 * get(v, 'python_share') if get(v, 'python_share') is not None else None, '.1f')} % "
                 f"| {fmt(get(v, 'cpus_used'), '.2f')} |")
    rows = get(edp, "rows")
    if rows:
        keys = [k for k in rows[0] if k != "batch"]
        L += ["", "EDP inference, chunks/s, one thread each (Rust runtime vs the same MLP + DDIM in PyTorch):", "",
              "| batch | " + " | ".join(keys) + " | Rust / PyTorch float32 |", "|---:|" + "---:|" * (len(keys) + 1)]
        for r in rows:
            L.append(f"| {r['batch']} | " + " | ".join(fmt(r[k]) for k in keys)
                     + f" | {ratio(rust_chunks(r), r.get(TORCH32_COLUMN), '.2f')} |")
    elif edp:
        L += ["", f"EDP inference: {edp.get('error', 'not measured')}"]
    return L


def report(meta, single, pandagym, vector, plot_name, latent=None, edp=None):
    m = meta
    L = [
        "# equigym performance suite", "",
        f"{m['date']} · `{m['command']}` · git {m['git']}", "",
        f"- machine: {m['cpu_model']}, {m['nproc']} logical CPUs, {m['platform']}",
        f"- load average (1/5/15 min): {m['load_start']} at start, {m['load_end']} at end; before each part: "
        + "; ".join(f"{k} {v}" for k, v in m["load_parts"].items()),
        f"- equigym side: {', '.join(f'{k} {v}' for k, v in m['versions'].items())}",
        f"- robosuite side: {', '.join(f'{k} {v}' for k, v in (m.get('robosuite_versions') or {}).items()) or '(not run)'}",
        f"- panda-gym side: {', '.join(f'{k} {v}' for k, v in (get(pandagym, 'versions') or {}).items()) or '(not run)'}",
        "- method: seeded uniform-random actions sampled before timing, warm-up, median of "
        f"{m['args']['reps']} repetitions; single-env figures pinned to CPU {m['args']['cpu']} on both sides; "
        "equigym unwrapped, robosuite `ignore_done=True`, panda-gym unwrapped. Physics-only = robosuite's recorded "
        "controls replayed through bare `mujoco.mj_step` (25 substeps per control step).",
        "",
        "## Single environment, one core", "",
        "| task | equigym steps/s | robosuite steps/s | ratio | robosuite physics-only steps/s | ratio | equigym reset ms | robosuite reset ms (hard / soft) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in single:
        e, s, p = get(r["equigym"], "steps_per_s"), get(r["robosuite"], "steps_per_s"), get(r["robosuite"], "physics_only_steps_per_s")
        L.append(f"| {r['id']} / {r['task']} | {fmt(e)} | {fmt(s)} | **{ratio(e, s)}** | {fmt(p)} | **{ratio(e, p)}** "
                 f"| {fmt(get(r['equigym'], 'reset_ms'), '.3f')} | {fmt(get(r['robosuite'], 'reset_ms_hard'), '.0f')} / "
                 f"{fmt(get(r['robosuite'], 'reset_ms_soft'), '.1f')} |")
    lift = next((r for r in single if r["id"] == "EquiLift-v0"), None)
    pg = get(pandagym, "steps_per_s")
    if pandagym is not None:
        le = get(lift["equigym"], "steps_per_s") if lift else None
        L += ["", "| peer | task | steps/s | reset ms | equigym Lift / peer |", "|---|---|---:|---:|---:|",
              f"| panda-gym (PyBullet) | PandaPickAndPlace-v3 (20 substeps at 2 ms, 25 Hz control) | {fmt(pg)} "
              f"| {fmt(get(pandagym, 'reset_ms'), '.2f')} | **{ratio(le, pg)}** |"]
        if "error" in pandagym:
            L.append(f"\npanda-gym error: {pandagym['error']}")
    L += ["", f"## Vector env ({m['args']['vector_task']}, `gymnasium.make_vec`, auto-reset on)", "",
          "Env steps/s of the whole batch; *Python share* = (wall time of `EquiVectorEnv.step` − time inside the "
          "Rust batched step) / wall time. T threads run pinned to the first T CPUs; the thread counts' repetitions "
          "alternate, each repetition the same reset seed and actions (the same trajectories) for every T, and "
          "*T=2 / T=1* is the median of the repetitions' ratios. *CPUs used* = process CPU "
          "time (all threads) / wall time during the timed steps: 2.0 would mean both cores were ours; on a machine "
          "busy with other work it shows how much CPU the run actually got, which bounds the thread scaling. "
          "*Ceiling* (B ≥ 16): a second, independent one-thread env in another process on the second CPU, "
          "stepping the same work at the same moment as the T=1 env on the first; their summed rate over the T=1 rate "
          "alone, median of the repetitions: what two cores of this machine give two copies that share nothing but "
          "the hardware, the most a 2-thread pool can reach here.", "",
          "| B | " + " | ".join(f"T={t} env steps/s | T={t} µs/step | T={t} Python share | T={t} CPUs used"
                               for t in m["args"]["threads"])
          + " | T=2 / T=1 | ceiling | reset ms (T=1) |",
          "|---:|" + "---:|---:|---:|---:|" * len(m["args"]["threads"]) + "---:|---:|---:|"]
    by = {(v["B"], v["threads"]): v for v in vector}
    for b in m["args"]["batch_sizes"]:
        cells = []
        for t in m["args"]["threads"]:
            v = by.get((b, t))
            cells += [fmt(get(v, "env_steps_per_s")), fmt(get(v, "step_us"), ",.0f"),
                      fmt(100 * get(v, "python_share") if get(v, "python_share") is not None else None, ".1f") + " %",
                      fmt(cpus_used(v), ".2f")]
        L.append(f"| {b} | " + " | ".join(cells) + f" | {times(scaling(by, b))} | {times(get(by.get((b, 1)), 'ceiling'))} "
                 f"| {fmt(get(by.get((b, 1)), 'reset_ms'), '.2f')} |")
    L += latent_section(m, latent, edp)

    # Targets.
    L += ["", "## Targets (ratios from this run)", "", "| target | measured | met |", "|---|---:|:---:|"]
    if lift:
        e, s, p = get(lift["equigym"], "steps_per_s"), get(lift["robosuite"], "steps_per_s"), get(lift["robosuite"], "physics_only_steps_per_s")
        for name, a, bb, tgt in (("Lift single env ≥ 1.2× robosuite's physics-only MuJoCo rate (the floor)", e, p, FLOOR_VS_PHYSICS_ONLY),
                                 ("Lift single env ≥ 3× robosuite's physics-only MuJoCo rate (the goal)", e, p, TARGET_VS_PHYSICS_ONLY),
                                 ("Lift single env ≥ 20× robosuite Lift", e, s, TARGET_VS_ROBOSUITE)):
            met = "–" if not (a and bb) else ("yes" if a / bb >= tgt else "**no**")
            L.append(f"| {name} | {ratio(a, bb)} | {met} |")
    scal = [(b, scaling(by, b)) for b in m["args"]["batch_sizes"]]
    scal = [(b, x) for b, x in scal if x]
    big = [s for b, s in scal if b >= SCALING_MIN_BATCH]
    if big:
        L.append(f"| vector env ≥ {TARGET_THREAD_SCALING}× on 2 threads over 1 (B ≥ {SCALING_MIN_BATCH}) | {min(big):.2f}× – {max(big):.2f}× | "
                 f"{'yes' if min(big) >= TARGET_THREAD_SCALING else ('partly' if max(big) >= TARGET_THREAD_SCALING else '**no**')} |")
    ceil = [(scaling(by, b), get(by.get((b, 1)), "ceiling")) for b in m["args"]["batch_sizes"] if b >= SCALING_MIN_BATCH]
    ceil = [(x, c) for x, c in ceil if x and c]
    if ceil:
        L.append(f"| (context) the machine's 2-core ceiling: two independent 1-thread copies over one (B ≥ {SCALING_MIN_BATCH}) "
                 f"| {min(c for _, c in ceil):.2f}× – {max(c for _, c in ceil):.2f}× | – |")
        L.append(f"| (context) the vector env's T=2 / T=1 as a share of that ceiling (B ≥ {SCALING_MIN_BATCH}) "
                 f"| {100 * min(x / c for x, c in ceil):.0f} % – {100 * max(x / c for x, c in ceil):.0f} % | – |")
    got = [cpus_used(by.get((b, 2))) for b in m["args"]["batch_sizes"] if b >= SCALING_MIN_BATCH]
    got = [g for g in got if g]
    if got:
        L.append(f"| (context) CPUs the 2-thread runs actually got (B ≥ {SCALING_MIN_BATCH}; 2.00 = both cores free) "
                 f"| {min(got):.2f} – {max(got):.2f} | – |")
    shares = [get(v, "python_share") for v in vector if get(v, "python_share") is not None]
    if shares:
        L.append(f"| Python share of a vector step < 10 % | {100 * min(shares):.1f} % – {100 * max(shares):.1f} % | "
                 f"{'yes' if max(shares) < TARGET_PYTHON_SHARE else '**no**'} |")
    L += ["", f"![throughput]({plot_name})", "",
          "Where a single-env step's time goes (perf, `bash benches/profile.sh`): [profile.md](profile.md).", ""]
    return "\n".join(L)


def plot(meta, single, pandagym, vector, path):
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        log("matplotlib missing: no plot (pip install matplotlib)")
        return False
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 4.6))
    labels, values, colors = [], [], []
    for r in single:
        short = r["id"].replace("Equi", "").replace("-v0", "")
        for name, v, c in ((f"equigym\n{short}", get(r["equigym"], "steps_per_s"), "tab:blue"),
                           (f"robosuite\n{short}", get(r["robosuite"], "steps_per_s"), "tab:red"),
                           (f"MuJoCo\nphysics-only\n{short}", get(r["robosuite"], "physics_only_steps_per_s"), "tab:orange")):
            if v:
                labels.append(name)
                values.append(v)
                colors.append(c)
    if get(pandagym, "steps_per_s"):
        labels.append("panda-gym\nPickAndPlace")
        values.append(get(pandagym, "steps_per_s"))
        colors.append("tab:green")
    ax1.bar(range(len(values)), values, color=colors)
    ax1.set_xticks(range(len(values)), labels, fontsize=6.5)
    ax1.set_yscale("log")
    ax1.set_ylabel("control steps/s (one core)")
    ax1.set_title("Single environment, one core")
    for i, v in enumerate(values):
        ax1.text(i, v * 1.08, f"{v:,.0f}", ha="center", fontsize=6.5)
    for t in meta["args"]["threads"]:
        pts = sorted((v["B"], v["env_steps_per_s"]) for v in vector if v.get("threads") == t and "error" not in v)
        if pts:
            ax2.plot([p[0] for p in pts], [p[1] for p in pts], "o-", label=f"equigym vector env, {t} thread(s)")
    lift = next((r for r in single if r["id"] == "EquiLift-v0"), None)
    for v, name, style in ((get(lift["robosuite"], "steps_per_s") if lift else None, "robosuite Lift (1 env)", "r--"),
                           (get(pandagym, "steps_per_s"), "panda-gym PickAndPlace (1 env)", "g--")):
        if v:
            ax2.axhline(v, color=style[0], ls="--", label=name)
    ax2.set_xscale("log", base=2)
    ax2.set_yscale("log")
    ax2.set_xlabel("B (environments per batch)")
    ax2.set_ylabel("environment steps/s")
    ax2.set_title(f"Vector env ({meta['args']['vector_task']}, auto-reset)")
    ax2.legend(fontsize=7, loc="center right")
    fig.suptitle(f"{meta['cpu_model']} ({meta['nproc']} CPUs), load {meta['load_start']} → {meta['load_end']}", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return True


README_BEGIN = "<!-- suite:begin (written by benches/suite.py --update-docs) -->"
README_END = "<!-- suite:end -->"
#: The page whose figures ``--update-docs`` rewrites between the markers.
PERFORMANCE_DOC = HERE.parent / "docs" / "performance.md"


def readme_block(meta, single, pandagym, vector, plot_rel, latent=None, edp=None):
    """The README's figures, from one suite run."""
    load0, load1 = meta["load_start"], meta["load_end"]
    busy = load0 and load0[0] > 0.7  # the end figure includes the suite's own 2-thread runs
    L = [README_BEGIN, "",
         f"`benches/suite.py`, {meta['date'][:10]}, git {meta['git']}: {meta['cpu_model']}, {meta['nproc']} CPUs; "
         f"load average {load0} at start, {load1} at end"
         + (" (**busy machine**: other engineers' builds and training shared the 2 cores, so absolute figures are low "
            "and thread scaling is understated; ratios are from the same run)" if busy else " (quiet machine at the start; the end figure includes the suite's own 2-thread runs)") + ".", "",
         "| single env, one core (uniform random actions) | equigym steps/s | peer steps/s | ratio |",
         "|---|---:|---:|---:|"]
    for r in single:
        e, s_, p = get(r["equigym"], "steps_per_s"), get(r["robosuite"], "steps_per_s"), get(r["robosuite"], "physics_only_steps_per_s")
        L.append(f"| {r['id']} vs robosuite {r['task']} | {fmt(e)} | {fmt(s_)} | **{ratio(e, s_)}** |")
        if r["id"] == "EquiLift-v0":
            L.append(f"| {r['id']} vs robosuite's physics only (bare `mj_step`, Lift model) | {fmt(e)} | {fmt(p)} | **{ratio(e, p)}** |")
    lift = next((r for r in single if r["id"] == "EquiLift-v0"), None)
    if lift and get(pandagym, "steps_per_s"):
        e = get(lift["equigym"], "steps_per_s")
        L.append(f"| EquiLift-v0 vs panda-gym PandaPickAndPlace-v3 | {fmt(e)} | {fmt(get(pandagym, 'steps_per_s'))} "
                 f"| **{ratio(e, get(pandagym, 'steps_per_s'))}** |")
    resets = [f"{fmt(get(r['equigym'], 'reset_ms'), '.3f')} ms" for r in single]
    rs = [get(r["robosuite"], "reset_ms_hard") for r in single if get(r["robosuite"], "reset_ms_hard")]
    L += ["", f"Reset: equigym {' / '.join(resets)} (" + ", ".join(r["id"] for r in single) + ")"
          + (f"; robosuite {min(rs):.0f}-{max(rs):.0f} ms (default hard reset)" if rs else "")
          + (f"; panda-gym {get(pandagym, 'reset_ms'):.2f} ms" if get(pandagym, "reset_ms") else "") + "."]
    by = {(v["B"], v["threads"]): v for v in vector}
    rows = []
    for b in meta["args"]["batch_sizes"]:
        v1, v2 = by.get((b, 1)), by.get((b, 2))
        r1, r2 = get(v1, "env_steps_per_s"), get(v2, "env_steps_per_s")
        sh = [x for x in (get(v1, "python_share"), get(v2, "python_share")) if x is not None]
        rows.append(f"| {b} | {fmt(r1)} | {fmt(r2)} | {times(scaling(by, b))} | {times(get(v1, 'ceiling'))} "
                    f"| {fmt(cpus_used(v1), '.2f')} / {fmt(cpus_used(v2), '.2f')} | {fmt(100 * max(sh) if sh else None, '.1f')} % |")
    L += ["", f"| vector env ({meta['args']['vector_task']}), B | env steps/s, 1 thread | 2 threads | 2 / 1 "
              "| 2-core ceiling (two independent 1-thread copies / one) | CPUs the run got, 1 / 2 threads "
              "| Python share of a step |", "|---:|---:|---:|---:|---:|---:|---:|"] + rows
    best = max((v for v in latent or [] if get(v, "latent_steps_per_s")), key=lambda v: v["latent_steps_per_s"], default=None)
    one = next((v for v in latent or [] if v["B"] == 1 and v["threads"] == 1 and get(v, "latent_steps_per_s")), None)
    if best and one:
        L += ["", f"Latent-action env (EquiLift-Latent-v0, batched DDIM + chunk): {fmt(one['latent_steps_per_s'])} latent "
                  f"steps/s for one env, {fmt(best['latent_steps_per_s'])} at B = {best['B']} on {best['threads']} "
                  f"thread(s) ({fmt(best['env_steps_per_s'])} env steps/s)."]
    rows = get(edp, "rows")
    if rows:
        L += ["", "EDP chunks/s, one thread: " + "; ".join(
            f"batch {r['batch']}: Rust {fmt(rust_chunks(r))} vs PyTorch {fmt(r[TORCH32_COLUMN])} (float32)"
            for r in rows) + "."]
    L += ["", f"![performance suite]({plot_rel})", "", README_END]
    return "\n".join(L)


def update_docs(block, path=None):
    path = path or PERFORMANCE_DOC
    text = path.read_text()
    if README_BEGIN not in text or README_END not in text:
        log(f"{path} has no suite markers; not updated")
        return
    head, rest = text.split(README_BEGIN, 1)
    _, tail = rest.split(README_END, 1)
    path.write_text(head + block + tail)
    log(f"updated {path}")


def write_outputs(args, meta, single, pandagym, vector, latent=None, edp=None):
    args.out.parent.mkdir(parents=True, exist_ok=True)
    png = args.out.with_suffix(".png")
    has_plot = plot(meta, single, pandagym, vector, png)
    md = report(meta, single, pandagym, vector, png.name if has_plot else "(no plot: matplotlib missing)", latent, edp)
    print(md)
    args.out.write_text(md)
    if args.update_docs:
        rel = os.path.relpath(png, PERFORMANCE_DOC.parent) if has_plot else "../benches/results/suite.md"
        update_docs(readme_block(meta, single, pandagym, vector, rel, latent, edp))
    log(f"wrote {args.out}" + (f", {png}" if has_plot else ""))


def pin_first(cpus, t):
    """Pin this process (and the threads it starts next) to the first t of ``cpus``."""
    try:
        os.sched_setaffinity(0, set(cpus[:t]) if len(cpus) >= t else set(cpus))
    except (AttributeError, OSError):
        pass


def main():
    args = parse_args()
    if args.from_json:
        data = json.loads(args.from_json.read_text())
        write_outputs(args, data["meta"], data["single"], data["pandagym"], data["vector"], data.get("latent"), data.get("edp"))
        return
    cpus = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    meta = {
        "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
        "command": shlex.join([Path(sys.executable).name, *sys.argv]),
        "cpu_model": peers.cpu_model(), "nproc": os.cpu_count(), "platform": peers.platform.platform(),
        "load_start": peers.loadavg(), "versions": peers.versions(), "git": peers.git_rev(),
        "args": {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()},
        "load_parts": {},
    }
    if meta["load_start"] and meta["load_start"][0] > 0.7:
        log(f"warning: load average {meta['load_start']}: the machine is busy, expect noisy numbers")

    # 1. single environment, one core
    peers.pin(args.cpu)
    run_rs = not args.no_peers and args.robosuite_python.exists()
    run_pg = not args.no_peers and args.pandagym_python.exists()
    for name, ok, path in (("robosuite", run_rs, args.robosuite_python), ("panda-gym", run_pg, args.pandagym_python)):
        if not ok and not args.no_peers:
            log(f"{name} venv not found ({path}); run bash benches/setup_peers.sh. Skipping {name}.")
    meta["load_parts"]["single"] = peers.loadavg()
    single = []
    for env_id in args.equigym_ids:
        task = peers.ROBOSUITE_TASKS.get(env_id)
        log(f"[{env_id}] equigym single env ...")
        row = {"id": env_id, "task": task, "equigym": peers.guarded(peers.bench_equigym, env_id, args), "robosuite": None}
        if run_rs and task:
            log(f"[{env_id}] robosuite {task} ...")
            row["robosuite"] = peers.guarded(peers.bench_robosuite, task, args)
            if not meta.get("robosuite_versions") and "versions" in row["robosuite"]:
                meta["robosuite_versions"] = row["robosuite"]["versions"]
        single.append(row)
    pandagym = None
    if run_pg:
        log("[panda-gym] PandaPickAndPlace-v3 ...")
        pandagym = peers.guarded(bench_pandagym, args)

    # 2. vector env, T threads pinned to the first T CPUs
    meta["load_parts"]["vector"] = peers.loadavg()
    vector = []
    for b in args.batch_sizes:
        log(f"[vector] B={b}, T={args.threads} alternating ...")
        got = peers.guarded(bench_vector, args.vector_task, b, args.threads, args)
        if isinstance(got, dict):  # an error: one entry per thread count
            got = [dict(got) for _ in args.threads]
        for t, v in zip(args.threads, got):
            v.setdefault("B", b)
            v.setdefault("threads", t)
            vector.append(v)

    # 3. latent-action vector env and EDP inference
    latent, edp = [], None
    if not args.no_latent:
        meta["load_parts"]["latent"] = peers.loadavg()
        for t in args.threads:
            pin_first(cpus, t)
            for b in args.latent_batch_sizes:
                log(f"[latent] B={b} T={t} ...")
                v = peers.guarded(bench_latent, b, t, args)
                v.setdefault("B", b)
                v.setdefault("threads", t)
                latent.append(v)
        pin_first(cpus, 1)
        log("[edp] chunks/s, Rust vs PyTorch ...")
        edp = peers.guarded(bench_edp, args)
    meta["load_end"] = peers.loadavg()

    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(json.dumps(
        {"meta": meta, "single": single, "pandagym": pandagym, "vector": vector, "latent": latent, "edp": edp}, indent=1) + "\n")
    write_outputs(args, meta, single, pandagym, vector, latent, edp)


if __name__ == "__main__":
    main()
