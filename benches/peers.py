#!/usr/bin/env python3
"""Side-by-side throughput: equigym vs robosuite, single process, one core.

Run with the equigym virtualenv's python; robosuite is timed in a subprocess using the venv
that benches/setup_peers.sh creates. Measurements take turns (never in parallel: the
benchmark machines have 2 cores) and every process is pinned to one CPU.

    python benches/peers.py                                   # EquiLift-v0, 3 x 2000 steps
    python benches/peers.py --equigym-ids EquiLift-v0 EquiStack-v0 EquiSquare-v0
    python benches/peers.py --quick                           # smoke test: 1 x 300 steps
    python benches/peers.py --rust-bin target/release/examples/throughput --rust-args 'lift 4000'

Method (matches shared/bench/peers, so robosuite numbers compare with RESULTS.md): seeded
uniform-random actions sampled before timing, reset(seed) then --warmup steps, then the
median over --reps runs of --steps env.step() calls. equigym runs unwrapped (no TimeLimit);
if an episode still ends, the reset is timed but kept out of the step time. robosuite runs
with ignore_done=True. Reset cost is timed separately as the median of --resets resets.
"""
import os

# One core means one thread everywhere; set before numpy/BLAS or rayon spin up pools.
for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "RAYON_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse
import datetime
import json
import platform
import re
import shlex
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
WORKER = HERE / "_robosuite_worker.py"
PEERS_DIR = Path(os.environ.get("EQUIGYM_PEERS_DIR", Path.home() / ".cache" / "equigym-peers"))
# equigym id -> robosuite task with the same goal (Panda, state obs).
ROBOSUITE_TASKS = {"EquiLift-v0": "Lift", "EquiStack-v0": "Stack", "EquiSquare-v0": "NutAssemblySquare"}


def parse_args():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--equigym-ids", nargs="+", default=["EquiLift-v0"],
                    help="gymnasium ids to time (space or comma separated)")
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--warmup", type=int, default=200)
    ap.add_argument("--resets", type=int, default=10, help="resets timed for the reset-cost median")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cpu", type=int, default=0, help="CPU every measurement is pinned to")
    ap.add_argument("--quick", action="store_true", help="smoke test: --steps 300 --reps 1 --resets 3")
    ap.add_argument("--rust-bin", help="pure-Rust example binary to time too, e.g. target/release/examples/throughput "
                         "(its output must contain 'N steps/s')")
    ap.add_argument("--rust-args", default="", help="arguments for --rust-bin, one shell-quoted string")
    ap.add_argument("--robosuite-python", type=Path, default=PEERS_DIR / "venv_robosuite" / "bin" / "python")
    ap.add_argument("--no-robosuite", action="store_true")
    ap.add_argument("--timeout", type=float, default=1800, help="seconds per subprocess")
    ap.add_argument("--out", type=Path, default=HERE / "results" / "peers.md",
                    help="Markdown report; raw JSON goes next to it with a .json suffix")
    args = ap.parse_args()
    if args.quick:
        args.steps, args.reps, args.resets = 300, 1, 3
    args.equigym_ids = [i for s in args.equigym_ids for i in s.split(",") if i]
    if args.rust_bin and os.sep in args.rust_bin:  # the binary runs with cwd=REPO (assets are repo-relative)
        args.rust_bin = str(Path(args.rust_bin).resolve())
    return args


def pin(cpu):
    try:
        os.sched_setaffinity(0, {cpu})
        return sorted(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # not Linux, or the cpu is not ours
        return None


def loadavg():
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:
        return None


def cpu_model():
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, timeout=10).stdout
        m = re.search(r"^Model name:\s*(.+)$", out, re.M)
        if m:
            return m.group(1).strip()
    except (OSError, subprocess.SubprocessError):
        pass
    return platform.processor() or platform.machine()


def git_rev():
    try:
        rev = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"],
                             capture_output=True, text=True, timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(REPO), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=10).stdout.strip()
        return rev + ("-dirty" if dirty else "") if rev else None
    except (OSError, subprocess.SubprocessError):
        return None


def versions():
    v = {"python": platform.python_version()}
    for mod in ("numpy", "gymnasium", "equigym"):
        try:
            v[mod] = getattr(__import__(mod), "__version__", "?")
        except Exception as e:  # equigym may not be built yet
            v[mod] = f"unavailable ({type(e).__name__}: {e})"
    return v


# ---------------------------------------------------------------- equigym (in process)

def run_steps(env, actions):
    """Step through actions; resets on episode end are timed apart from the steps."""
    pc = time.perf_counter
    resets = []
    t0 = pc()
    for a in actions:
        _, _, terminated, truncated, _ = env.step(a)
        if terminated or truncated:
            r0 = pc()
            env.reset()
            resets.append(pc() - r0)
    return pc() - t0 - sum(resets), resets


def bench_equigym(env_id, args):
    import gymnasium
    try:
        import equigym  # noqa: F401  (registers the Equi* ids)
    except ImportError:
        if env_id.startswith("Equi"):
            raise
    t0 = time.perf_counter()
    env = gymnasium.make(env_id).unwrapped  # no TimeLimit / checker wrappers in the loop
    res = {"id": env_id, "make_s": time.perf_counter() - t0, "load_before": loadavg()}
    space = env.action_space
    space.seed(args.seed)
    res["action_space"] = str(space)

    def actions(n):  # sampled up front so sampling cost stays out of the timing
        return [space.sample() for _ in range(n)]

    env.reset(seed=args.seed)
    run_steps(env, actions(args.warmup))
    secs, ep_resets = [], []
    for _ in range(args.reps):
        s, r = run_steps(env, actions(args.steps))
        secs.append(s)
        ep_resets += r
    res["steps_per_s_runs"] = [args.steps / s for s in secs]
    res["steps_per_s"] = statistics.median(res["steps_per_s_runs"])
    res["episode_resets_in_runs"] = len(ep_resets)

    ts = []
    for _ in range(args.resets):
        r0 = time.perf_counter()
        env.reset()
        ts.append(time.perf_counter() - r0)
    res["reset_ms"] = 1e3 * statistics.median(ts)
    if ep_resets:
        res["episode_reset_ms"] = 1e3 * statistics.median(ep_resets)
    env.close()
    return res


def bench_rust(args):
    """The Rust example prints its own rate; run it --reps times and take the median."""
    cmd = [args.rust_bin, *shlex.split(args.rust_args)]
    res = {"cmd": shlex.join(cmd), "load_before": loadavg()}
    rates = []
    for _ in range(args.reps):
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=args.timeout, cwd=REPO)
        # examples/throughput prints "N control steps/s (stepping only: M)"; M excludes resets, like ours.
        found = (re.findall(r"stepping only:\s*([\d.]+)", p.stdout)
                 or re.findall(r"([\d.]+)\s*(?:[A-Za-z]+\s+)?steps/s", p.stdout))
        if p.returncode != 0 or not found:
            raise RuntimeError(f"rc={p.returncode}, no 'steps/s' in output: {(p.stdout + p.stderr)[-500:]}")
        rates.append(float(found[-1]))
        res["last_line"] = p.stdout.strip().splitlines()[-1]
    res["steps_per_s_runs"] = rates
    res["steps_per_s"] = statistics.median(rates)
    return res


# ---------------------------------------------------------------- robosuite (subprocess)

def run_worker(python, worker, extra, args, env=None):
    """Run a peer's timing worker (``benches/_*_worker.py``) with that peer's venv ``python`` and
    the shared timing options of ``args``; its result is the last JSON line of its stdout (peers
    log to stdout on import), with the load average before the run added."""
    cmd = [str(python), str(worker), *extra]
    for name in ("steps", "reps", "warmup", "resets", "seed", "cpu"):
        cmd += [f"--{name}", str(getattr(args, name))]
    load = loadavg()
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=args.timeout, env=env)
    for line in reversed(p.stdout.splitlines()):
        if line.startswith("{"):
            res = json.loads(line)
            res["load_before"] = load
            return res
    raise RuntimeError(f"worker rc={p.returncode}: {(p.stderr or p.stdout)[-800:]}")


def bench_robosuite(task, args):
    return run_worker(args.robosuite_python, WORKER, ["--task", task], args, env=dict(os.environ, MUJOCO_GL="egl"))


# ---------------------------------------------------------------- report

def fmt(x, spec=",.0f"):
    return "–" if x is None else format(x, spec)


def ratio(a, b):
    return f"{a / b:.2f}×" if a and b else "–"


def cell(res, key):
    if res is None:
        return None, "–"
    if "error" in res:
        return None, "error"
    return res.get(key), fmt(res.get(key))


def report(meta, rows, rust):
    m = meta
    lines = [
        "# equigym vs robosuite: single-process, one-core throughput", "",
        f"{m['date']} · `{m['command']}`", "",
        f"- CPU: {m['cpu_model']} ({m['nproc']} logical CPUs visible), every measurement pinned to "
        f"{m['affinity'] if m['affinity'] is not None else 'no CPU (pinning unavailable)'}",
        f"- load average (1/5/15 min): {m['load_start']} at start, {m['load_end']} at end",
        f"- equigym side: {', '.join(f'{k} {v}' for k, v in m['versions'].items())}; git {m['git']}",
        f"- robosuite side: {', '.join(f'{k} {v}' for k, v in (m.get('robosuite_versions') or {}).items()) or 'not run (' + str(m['robosuite_skipped']) + ')'}",
        f"- method: seeded uniform-random actions, {m['args']['warmup']} warm-up steps, median of "
        f"{m['args']['reps']} × {m['args']['steps']} steps; equigym unwrapped, robosuite ignore_done=True; "
        "physics-only = robosuite's recorded ctrl replayed through bare mujoco.mj_step "
        "(mj_step/s ÷ substeps per env step)", "",
        "| task | equigym steps/s | robosuite steps/s | ratio | robosuite physics-only steps/s | ratio |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        e, es = cell(r["equigym"], "steps_per_s")
        s, ss = cell(r["robosuite"], "steps_per_s")
        p, ps = cell(r["robosuite"], "physics_only_steps_per_s")
        task = r["id"] + (f" / {r['task']}" if r["task"] else "")
        lines.append(f"| {task} | {es} | {ss} | {ratio(e, s)} | {ps} | {ratio(e, p)} |")
    lines += ["", "| task | equigym reset ms | robosuite reset ms (hard_reset=True) | robosuite reset ms (hard_reset=False) |",
              "|---|---:|---:|---:|"]
    for r in rows:
        e, s = r["equigym"] or {}, r["robosuite"] or {}
        lines.append(f"| {r['id']} | {fmt(e.get('reset_ms'), '.2f')} | {fmt(s.get('reset_ms_hard'), '.1f')} "
                     f"| {fmt(s.get('reset_ms_soft'), '.2f')} |")
    if rust is not None:
        lines.append("")
        if "error" in rust:
            lines.append(f"Pure-Rust binary `{rust['cmd']}`: error: {rust['error']}")
        else:
            lines.append(f"Pure-Rust binary `{rust['cmd']}` (its own action policy and step count; median of the rate it prints): "
                         f"{fmt(rust['steps_per_s'])} steps/s over {len(rust['steps_per_s_runs'])} run(s); "
                         f"last line: `{rust['last_line']}`")
    errors = [(r["id"], side, r[side]["error"]) for r in rows for side in ("equigym", "robosuite")
              if r[side] and "error" in r[side]]
    if errors:
        lines += ["", "Errors:"] + [f"- {i} ({side}): {err}" for i, side, err in errors]
    return "\n".join(lines) + "\n"


def guarded(fn, *a):
    try:
        return fn(*a)
    except Exception as e:  # one broken side must not lose the other's numbers
        return {"error": f"{type(e).__name__}: {e}".strip()[:1000]}


def main():
    args = parse_args()
    affinity = pin(args.cpu)
    load_start = loadavg()
    if load_start and load_start[0] > 0.7:
        print(f"warning: load average {load_start} — the machine is busy, expect noisy numbers", file=sys.stderr)

    run_robosuite = not args.no_robosuite
    if run_robosuite and not args.robosuite_python.exists():
        print(f"robosuite venv not found ({args.robosuite_python}).\n"
              f"  Create it with:  bash {HERE / 'setup_peers.sh'}\n"
              "  Reporting equigym numbers only.", file=sys.stderr)
        run_robosuite = False

    meta = {
        "robosuite_skipped": None if run_robosuite else
        ("--no-robosuite" if args.no_robosuite else f"no venv at {args.robosuite_python}; run benches/setup_peers.sh"),
        "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
        "command": shlex.join([Path(sys.executable).name, *sys.argv]),
        "cpu_model": cpu_model(), "nproc": os.cpu_count(), "affinity": affinity,
        "platform": platform.platform(), "load_start": load_start,
        "versions": versions(), "git": git_rev(),
        "args": {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()},
    }

    rows = []
    for env_id in args.equigym_ids:  # equigym then robosuite per task, so both see similar load
        task = ROBOSUITE_TASKS.get(env_id)
        print(f"[{env_id}] equigym ...", file=sys.stderr, flush=True)
        row = {"id": env_id, "task": task, "equigym": guarded(bench_equigym, env_id, args), "robosuite": None}
        if "error" in row["equigym"]:
            print(f"[{env_id}] equigym error: {row['equigym']['error']}", file=sys.stderr)
        if run_robosuite and task:
            print(f"[{env_id}] robosuite {task} ...", file=sys.stderr, flush=True)
            row["robosuite"] = guarded(bench_robosuite, task, args)
            if "error" in row["robosuite"]:
                print(f"[{env_id}] robosuite error: {row['robosuite']['error']}", file=sys.stderr)
            elif not meta.get("robosuite_versions"):
                meta["robosuite_versions"] = row["robosuite"]["versions"]
        rows.append(row)

    rust = None
    if args.rust_bin:
        print(f"[rust] {args.rust_bin} ...", file=sys.stderr, flush=True)
        rust = guarded(bench_rust, args)
        rust.setdefault("cmd", shlex.join([args.rust_bin, *shlex.split(args.rust_args)]))
    meta["load_end"] = loadavg()

    md = report(meta, rows, rust)
    print(md)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(md)
    args.out.with_suffix(".json").write_text(json.dumps({"meta": meta, "results": rows, "rust": rust}, indent=1) + "\n")
    print(f"wrote {args.out} and {args.out.with_suffix('.json')}", file=sys.stderr)


if __name__ == "__main__":
    main()
