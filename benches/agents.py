"""Rust steering agents against SB3 (+ escnn), and the Rust DDIM runtime against PyTorch, on one
thread; writes benches/results/agents.md.

    CARGO_BUILD_JOBS=1 cargo build --release -p equigym-agents --example bench
    .venv/bin/python benches/agents.py [--quick] [--repeats 3]

- gradient steps/s of SAC (batch 256, Lift-sized observation and latent) for DSRL, Equi-DSRL and
  Approx-Equi-DSRL at the cpu preset (3 x 64 and parameter-matched equivariant nets) and at
  3 x 256: Rust (`agents/examples/bench.rs`) and SB3 (`baselines.steer.build`, torch on one
  thread, escnn for the equivariant nets), on random replay data;
- the core's measured f32 FMA peak and the Rust gemm kernel's GFLOP/s on the layer shapes;
- DDIM chunks/s of the shipped Lift EDP at batch 1, 16 and 256: Rust (float32 and float64) and
  PyTorch (float32).
Timings are CPU seconds of this process (`time.process_time`, one thread), so other load on the
machine distorts them less than wall time would.
"""

from __future__ import annotations

import argparse
import platform
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # baselines/ (run from a checkout)

ROOT = Path(__file__).resolve().parents[1]


def cpu_name() -> str:
    for line in Path("/proc/cpuinfo").read_text().splitlines():
        if line.startswith("model name"):
            return line.split(":", 1)[1].strip()
    return platform.processor()


def sb3_steps_per_s(method: str, width: int, steps: int) -> float:
    import torch
    from stable_baselines3.common.logger import configure

    from baselines.steer import PRESETS, build

    torch.set_num_threads(1)
    preset = {"name": "bench", **PRESETS["cpu"], "width": width}
    model, _ = build(method, "lift", preset, 0, True, None)
    model.set_logger(configure(None, []))
    rng = np.random.default_rng(0)
    od, ad = model.observation_space.shape[0], model.action_space.shape[0]
    for _ in range(2048 // 4):
        obs = rng.standard_normal((4, od)).astype(np.float32)
        act = rng.uniform(-1, 1, (4, ad)).astype(np.float32)
        model.replay_buffer.add(
            obs, obs, act, -rng.integers(0, 5, 4).astype(np.float32), np.zeros(4), [{} for _ in range(4)]
        )
    model._current_progress_remaining = 1.0
    model.train(gradient_steps=2, batch_size=256)
    t = time.process_time()
    model.train(gradient_steps=steps, batch_size=256)
    return steps / (time.process_time() - t)


def rust_kernels(quick: bool) -> dict[str, float]:
    exe = ROOT / "target" / "release" / "examples" / "bench"
    args = [str(exe), "--kernels"] + (["--quick"] if quick else [])
    out = subprocess.run(args, capture_output=True, text=True, check=True).stdout
    rows = {}
    for line in out.splitlines():
        if line.startswith("| ") and not line.startswith("| measure"):
            k, v = line.strip("| \n").rsplit("|", 1)
            rows[k.strip()] = float(v)
    return rows


def rust_steps_per_s(method: str, width: int, steps: int) -> tuple[float, int]:
    """Gradient steps/s of the Rust agent (`examples/bench --only`), and its regular fields."""
    exe = ROOT / "target" / "release" / "examples" / "bench"
    args = [str(exe), "--only", method, "--width", str(width), "--steps", str(steps)]
    out = subprocess.run(args, capture_output=True, text=True, check=True).stdout
    m = re.search(r"\((\d+) fields\): ([0-9.]+) gradient steps/s", out)
    if m is None:
        raise RuntimeError(f"unexpected output of {' '.join(args)}: {out!r}")
    return float(m.group(2)), int(m.group(1))


def ddim_chunks_per_s(batch: int, reps: int) -> tuple[float, float, float]:
    import torch

    import equigym
    from baselines.edp import ExportedPolicy
    from equigym.latent import shipped_policy

    torch.set_num_threads(1)
    path = shipped_policy("lift")
    rust = equigym.DiffusionPolicy(str(path))
    torch_p = ExportedPolicy(path, torch.float32)
    rng = np.random.default_rng(0)
    obs = rng.standard_normal((batch, rust.obs_dim)) * 0.1
    w = rng.standard_normal((batch, rust.action_dim))

    def rate(f) -> float:
        f()
        t = time.process_time()
        for _ in range(reps):
            f()
        return batch * reps / (time.process_time() - t)

    return (
        rate(lambda: rust.sample(obs, w)),
        rate(lambda: rust.sample(obs, w, precision="f64")),
        rate(lambda: torch_p.sample(obs, w)),
    )


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--quick", action="store_true")
    p.add_argument("--repeats", type=int, default=3, help="alternating Rust / SB3 measurements per cell")
    p.add_argument("--out", default=str(ROOT / "benches" / "results" / "agents.md"))
    a = p.parse_args()
    repeats = 1 if a.quick else a.repeats
    load_before = Path("/proc/loadavg").read_text().split()[:3]
    r = rust_kernels(a.quick)
    lines = [
        "# Rust steering agents vs SB3, one thread",
        "",
        f"`python benches/agents.py{' --quick' if a.quick else ''}` on {cpu_name()} ({time.strftime('%Y-%m-%d')}); "
        "CPU seconds of one thread, batch 256, Lift-sized inputs, random replay data. Each cell is the best of "
        f"{repeats} measurements, Rust and SB3 alternating (the range in brackets): on a shared machine the same "
        "binary's rate moves by up to 1.3x from minute to minute, and the best run is the one least disturbed.",
        "",
        "| gradient steps/s | Rust | SB3 | Rust / SB3 |",
        "|---|---:|---:|---:|",
    ]
    for width, label in ((64, "cpu preset (3 x 64)"), (256, "3 x 256")):
        # steps per measurement: about 2-5 s each at the rates of an AVX-512 Xeon core
        rust_n = (50 if a.quick else 300) if width == 64 else (10 if a.quick else 60)
        sb3_n = (10 if a.quick else 60) if width == 64 else (5 if a.quick else 20)
        for method in ("dsrl", "equi", "approx"):
            rust, sb3, fields = [], [], 0
            for _ in range(repeats):
                sps, fields = rust_steps_per_s(method, width, rust_n)
                rust.append(sps)
                try:
                    sb3.append(sb3_steps_per_s(method, width, sb3_n))
                except ImportError as e:  # escnn missing: the Rust column alone
                    print(f"SB3 {method}: {e}", file=sys.stderr)
                    sb3.append(float("nan"))
            f = f" {fields} fields" if fields else ""

            def cell(v: list[float]) -> str:
                return f"{max(v):.1f}" + (f" ({min(v):.1f}-{max(v):.1f})" if len(v) > 1 else "")

            lines.append(f"| {method} {label}{f} | {cell(rust)} | {cell(sb3)} | {max(rust) / max(sb3):.1f}x |")
            print(lines[-1], flush=True)
    lines += ["", "| kernel | GFLOP/s |", "|---|---:|"]
    peak = r.get("f32 FMA peak, one core (GFLOP/s)", float("nan"))
    for k, v in r.items():
        if k.startswith("gemm") or k.startswith("f32 FMA"):
            frac = f" ({100 * v / peak:.0f} % of peak)" if k.startswith("gemm") else ""
            lines.append(f"| {k.replace(' (GFLOP/s)', '')} | {v:.1f}{frac} |")
    lines += [
        "",
        "| DDIM chunks/s (Lift EDP, 5 steps) | Rust f32 | Rust f64 | PyTorch f32 | Rust f32 / PyTorch |",
        "|---|---:|---:|---:|---:|",
    ]
    for batch, reps in ((1, 400), (16, 100), (256, 10)):
        reps = max(2, reps // 10) if a.quick else reps
        rf, r64, tf = ddim_chunks_per_s(batch, reps)
        lines.append(f"| batch {batch} | {rf:,.0f} | {r64:,.0f} | {tf:,.0f} | {rf / tf:.2f}x |")
    load_after = Path("/proc/loadavg").read_text().split()[:3]
    lines += [
        "",
        f"Load average (1, 5, 15 min) when the benchmark started: {', '.join(load_before)}; when it ended: "
        f"{', '.join(load_after)}. Other load slows both columns alike (CPU time of one thread), so the ratios "
        "are the figures to compare across runs.",
    ]
    text = "\n".join(lines) + "\n"
    Path(a.out).write_text(text)
    print(text)


if __name__ == "__main__":
    main()
