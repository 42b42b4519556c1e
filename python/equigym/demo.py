"""Scripted-expert rollouts: success rate, throughput and pictures.

python -m equigym.demo --env EquiLift-v0 --episodes 50 --out runs/demo
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import gymnasium
import numpy as np

import equigym
from equigym._optional import require
from equigym.rendering import save_gif


def run(env_id: str, episodes: int, out: Path, noise: float, seed: int) -> dict[str, float]:
    env = gymnasium.make(env_id, render_mode="rgb_array", render_width=320, render_height=240)
    core = env.unwrapped.core
    expert = equigym.Expert(core.task, position_noise=noise)
    successes, steps, lengths = 0, 0, []
    start = time.perf_counter()
    for ep in range(episodes):
        env.reset(seed=seed + ep)
        expert.reset(core, seed + ep)
        for t in range(core.horizon):  # noqa: B007 (t is the episode length below)
            _, _, terminated, truncated, info = env.step(expert.act(core))
            steps += 1
            if info["success"] or terminated or truncated:
                break
        successes += bool(info["success"])
        lengths.append(t + 1)
    elapsed = time.perf_counter() - start

    # One episode rendered, kept going a little after success so the lift is visible.
    out.mkdir(parents=True, exist_ok=True)
    env.reset(seed=seed)
    expert.reset(core, seed)
    frames = [env.render()]
    after = 0
    for _ in range(core.horizon):
        _, _, _, _, info = env.step(expert.act(core))
        frames.append(env.render())
        after += bool(info["success"])
        if after > 10:
            break
    image = require("PIL.Image", "saving the demo's picture")
    image.fromarray(frames[-1]).save(out / f"{env_id}.png")
    save_gif(frames, out / f"{env_id}.gif")
    env.close()
    return {
        "success_rate": successes / episodes,
        "steps_per_s": steps / elapsed,
        "mean_length": float(np.mean(lengths)),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--env", nargs="+", default=["EquiLift-v0"])
    ap.add_argument("--episodes", type=int, default=50)
    ap.add_argument("--noise", type=float, default=0.0, help="expert position noise (m)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=Path("runs/demo"))
    args = ap.parse_args()
    print("| env | expert success | mean episode length | control steps/s (incl. Python) |")
    print("|---|---:|---:|---:|")
    for env_id in args.env:
        r = run(env_id, args.episodes, args.out, args.noise, args.seed)
        print(
            f"| {env_id} | {r['success_rate']:.3f} ({args.episodes} episodes) | {r['mean_length']:.1f} | {r['steps_per_s']:.0f} |"
        )
    print(f"pictures: {args.out}/<env>.png and .gif")


if __name__ == "__main__":
    main()
