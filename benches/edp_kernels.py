"""The diffusion-policy runtime's two kernels side by side: DDIM chunks/s of each shipped EDP,
its regular-to-regular layers dense or in the Fourier basis (float32, one thread); writes
benches/results/edp_kernels.md.

    .venv/bin/python benches/edp_kernels.py [--repeats 3] [--batch 256]

Batch 256 is what a noise-aliased gradient step decodes (twice per step), the cost of a steering
run on Stack D1 and Square D2. Each figure is the best of ``--repeats`` measurements, the
kernels alternating; timings are CPU seconds of this process (``time.process_time``), so other
load on the machine distorts them less than wall time would. The last column is the largest
difference between the two kernels' chunks (absolute actions) on the same inputs: the same map
up to float rounding, not the same bits.

The second table asks what those last bits do to whole episodes: the base policy (noise
N(0, I), noise seed 0) on the pinned evaluation starts with each kernel, the same starts and the
same noises, and how many episodes end the other way (``--episodes 0`` skips it).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def cpu_name() -> str:
    for line in Path("/proc/cpuinfo").read_text().splitlines():
        if line.startswith("model name"):
            return line.split(":", 1)[1].strip()
    return "an unknown CPU"


def chunks_per_s(policy, obs: np.ndarray, w: np.ndarray, seconds: float) -> float:
    policy.sample(obs, w)
    n, t = 0, time.process_time()
    while time.process_time() - t < seconds:
        policy.sample(obs, w)
        n += 1
    return len(obs) * n / (time.process_time() - t)


def outcomes_table(episodes: int, threads: int) -> list[str]:
    """The base policy's episodes on each kernel, paired by start: the rollouts' sensitivity to
    the last bits of a chunk (McNemar's exact test on the discordant starts)."""
    from equigym import DiffusionPolicy, _core
    from equigym.latent import shipped_policy
    from equigym.steer.stats import mcnemar_p

    lines = [
        "",
        f"The base policy (noise N(0, I), noise seed 0) on the {episodes} pinned evaluation starts with each kernel: "
        "the same starts and noise streams; on the same input the two chunks differ only by float rounding (the "
        "table above). *Differ*: "
        "the starts that succeed on one kernel and fail on the other (dense only / Fourier only); p: McNemar's "
        "exact test that neither kernel succeeds more often.",
        "",
        "| shipped EDP | dense | Fourier | starts whose outcome differs | dense only / Fourier only | p |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for task in ("lift", "stack", "square"):
        path = str(shipped_policy(task))
        env = {"variant": DiffusionPolicy(path).metadata.get("variant") or None}
        out = {
            kernel: _core.evaluate_base(
                task, seed=0, episodes=episodes, policy=path, edp_kernel=kernel, env=env, threads=threads
            )["outcomes"]
            for kernel in ("dense", "fourier")
        }
        pairs = list(zip(out["dense"], out["fourier"]))
        dense_only = sum(d and not f for d, f in pairs)
        fourier_only = sum(f and not d for d, f in pairs)
        differ = dense_only + fourier_only
        p = mcnemar_p(dense_only, fourier_only)
        lines.append(
            f"| {task} | {sum(out['dense'])}/{episodes} | {sum(out['fourier'])}/{episodes} | "
            f"{differ} ({differ / episodes:.0%}) | {dense_only} / {fourier_only} | {p:.2f} |"
        )
        print(lines[-1], flush=True)
    return lines


def main() -> None:
    from equigym import DiffusionPolicy
    from equigym.latent import shipped_policy

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--batch", type=int, default=256)
    p.add_argument("--seconds", type=float, default=2.0, help="CPU seconds per measurement")
    p.add_argument("--episodes", type=int, default=200, help="pinned starts per kernel for the rollout table")
    p.add_argument("--threads", type=int, default=2, help="rollout threads (the outcomes do not depend on it)")
    p.add_argument("--out", default=str(ROOT / "benches" / "results" / "edp_kernels.md"))
    a = p.parse_args()
    lines = [
        "# The EDP runtime's kernels: dense against the Fourier basis",
        "",
        f"`python benches/edp_kernels.py --repeats {a.repeats} --batch {a.batch} --episodes {a.episodes}` on "
        f"{cpu_name()} "
        f"({time.strftime('%Y-%m-%d')}): "
        f"DDIM chunks/s at batch {a.batch}, float32, one thread, best of {a.repeats} (range in brackets), the "
        "kernels alternating. Load average when it started: "
        + ", ".join(Path("/proc/loadavg").read_text().split()[:3])
        + ".",
        "",
        "| shipped EDP | Fourier layers | dense | Fourier | Fourier / dense | largest chunk difference |",
        "|---|---|---:|---:|---:|---:|",
    ]
    for task in ("lift", "stack", "square"):
        path = str(shipped_policy(task))
        dense, fourier = DiffusionPolicy(path, kernel="dense"), DiffusionPolicy(path, kernel="fourier")
        rng = np.random.default_rng(0)
        obs = rng.standard_normal((a.batch, dense.obs_dim)) * 0.1
        w = rng.standard_normal((a.batch, dense.action_dim))
        rates: dict[str, list[float]] = {"dense": [], "fourier": []}
        for _ in range(a.repeats):
            for name, policy in (("dense", dense), ("fourier", fourier)):
                rates[name].append(chunks_per_s(policy, obs, w, a.seconds))
        diff = float(np.abs(dense.sample(obs, w) - fourier.sample(obs, w)).max())

        def cell(v: list[float]) -> str:
            return f"{max(v):,.0f}" + (f" ({min(v):,.0f}-{max(v):,.0f})" if len(v) > 1 else "")

        lines.append(
            f"| {task} | {fourier.fourier_layers} | {cell(rates['dense'])} | {cell(rates['fourier'])} | "
            f"{max(rates['fourier']) / max(rates['dense']):.1f}x | {diff:.1e} |"
        )
        print(lines[-1], flush=True)
    if a.episodes:
        lines += outcomes_table(a.episodes, a.threads)
    text = "\n".join(lines) + "\n"
    Path(a.out).write_text(text)
    print(text)


if __name__ == "__main__":
    main()
