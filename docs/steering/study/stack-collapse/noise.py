"""What the EDP needs of its noise: the base policy with N(0, I) noise whose chunks are drawn
independently (as the EDP was trained and as the base runs), correlated across an episode's
chunks, held fixed, or shifted.

    python docs/steering/study/stack-collapse/noise.py [--task stack] [--episodes 300]

Every arm runs the shipped EDP from the same pinned evaluation starts (``EVAL_SEED`` + k), its
noise drawn from the same stream (numpy ``default_rng(k)``), clipped to the latent bound:

- *AR(1), rho*: chunk t's noise is ``rho * w[t-1] + sqrt(1 - rho^2) * z[t]``, ``z`` iid N(0, I),
  so every chunk's noise is still N(0, I) and only its correlation with the previous chunk's
  changes; rho = 0 is the base, rho = 1 one noise for the whole episode: the deterministic
  closed loop that a steering actor becomes when it picks the noise as a function of the state
  alone (its mean, or a sample whose spread has collapsed).
- *shifted*: iid N(0, I) plus a fixed vector on the chunk's invariant coordinates, the
  direction every trained Stack D1 learner's noise has in common (``noise-means.md``; z of
  every action +0.35, gripper width -0.3).

Per arm: successes with Wilson 95 %; against the base, the starts that end the other way (base
only / arm only) and McNemar's exact p; among the failures, the mean share of their chunks whose
commanded hand position (the chunk's mean) moved by less than 2 mm from the previous chunk's
(*stalled*: the measure `steer eval` reports as ``failures_stalled``), and the median of that
move. Writes ``noise-<task>.md`` beside this file.
"""

from __future__ import annotations

import argparse
import math
import statistics
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
#: AR(1) coefficients of the correlated arms (0: the base).
RHOS = (0.0, 0.5, 0.9, 1.0)
#: The shifted arm's offsets per action of the chunk: (action field, index in it) -> latent units.
SHIFT = {("position", 2): 0.35, ("gripper_width", 0): -0.3}


def rollout(
    env, start: int, k: int, rho: float, shift: np.ndarray, effect: list[np.ndarray], position: slice
) -> tuple[bool, list[float]]:
    """One episode; its outcome and the commanded hand position's move from chunk to chunk. With
    a shift, what it does to each chunk (the shifted noise's chunk minus the unshifted one's at
    the same state, per action coordinate, averaged over the chunk's actions) goes to ``effect``.
    ``position``: the hand position's slice of one action."""
    rng = np.random.default_rng(k)
    env.reset(start)
    w = rng.standard_normal(env.latent_dim)
    moves: list[float] = []
    last = None
    success = False
    while True:
        # The unshifted noise's chunk at this state, before the step moves it on.
        plain = np.asarray(env.decode(np.clip(w, -env.bound, env.bound))) if shift.any() else None
        _, _, terminated, truncated, info = env.step(np.clip(w + shift, -env.bound, env.bound))
        chunk = np.asarray(env.last_chunk())
        if plain is not None:
            effect.append((chunk - plain).reshape(-1, env.spec.action_dim).mean(axis=0))
        target = chunk.reshape(-1, env.spec.action_dim)[:, position].mean(axis=0)
        if last is not None:
            moves.append(float(np.linalg.norm(target - last)))
        last = target
        success = success or bool(info["success"])
        if success or terminated or truncated:
            return success, moves
        w = rho * w + math.sqrt(1.0 - rho * rho) * rng.standard_normal(env.latent_dim)


def arm(env, episodes: int, rho: float, shift: np.ndarray, position: slice) -> dict:
    from equigym import _core

    outcomes, stalled, moves, effect = [], [], [], []
    for k in range(episodes):
        ok, m = rollout(env, _core.EVAL_SEED + k, k, rho, shift, effect, position)
        outcomes.append(ok)
        if not ok and m:
            stalled.append(sum(x < _core.STALL_MOVE for x in m) / len(m))
            moves.append(statistics.median(m))
    return {"outcomes": outcomes, "stalled": stalled, "moves": moves, "effect": effect}


def row(label: str, res: dict, base: list[bool] | None) -> str:
    from equigym.steer.stats import format_pooled, mcnemar_p

    o = res["outcomes"]
    if base is None:
        vs = "| - | - "
    else:
        base_only = sum(b and not x for b, x in zip(base, o))
        arm_only = sum(x and not b for b, x in zip(base, o))
        vs = f"| {base_only} / {arm_only} | {mcnemar_p(base_only, arm_only):.3f} "
    fails = len(res["stalled"])
    stalled = f"{statistics.mean(res['stalled']):.2f}" if fails else "-"
    move = f"{1000 * statistics.median(res['moves']):.1f}" if fails else "-"
    return f"| {label} | {format_pooled(sum(o), len(o))} {vs}| {fails} | {stalled} | {move} |"


def main() -> None:
    from equigym import DiffusionPolicy, _core
    from equigym.envs import layout_slices
    from equigym.latent import shipped_policy

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", default="stack", choices=("lift", "stack", "square"))
    p.add_argument("--episodes", type=int, default=300)
    p.add_argument("--edp-kernel", default="dense", choices=("dense", "fourier"))
    p.add_argument("--out", default=None, help="default: noise-<task>.md beside this file")
    a = p.parse_args()
    policy = DiffusionPolicy(shipped_policy(a.task), kernel=a.edp_kernel)
    env = _core.LatentEnv(a.task, policy, variant=policy.metadata.get("variant") or None)
    fields = layout_slices(env.spec.action_layout)
    shift = np.zeros(env.latent_dim)
    for t in range(env.chunk_len):
        for (name, i), v in SHIFT.items():
            shift[t * env.spec.action_dim + fields[name].start + i] = v
    started = time.time()
    lines = [
        f"# What the EDP needs of its noise ({a.task})",
        "",
        f"`python docs/steering/study/stack-collapse/noise.py --task {a.task} --episodes {a.episodes} "
        f"--edp-kernel {a.edp_kernel}`: the shipped EDP on the pinned starts {_core.EVAL_SEED} + k, the same "
        "noise stream in every arm (the script's docstring says how each arm draws it). *Ends the other way*: "
        "starts that succeed with the base only / with the arm only, and McNemar's exact p. *Stalled*: among the "
        f"failures, the mean share of their chunks whose commanded hand position moved less than {1000 * _core.STALL_MOVE:g} "
        "mm from the previous chunk's; *move*: the median over failures of their median move.",
        "",
        "| noise | success (Wilson 95 %) | ends the other way | p | failures | stalled | move (mm) |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    base = None
    effects: list[str] = []
    arms = [
        (
            f"AR(1), rho = {r:g}" + (" (the base: iid)" if r == 0 else " (one noise per episode)" if r == 1 else ""),
            r,
            np.zeros_like(shift),
        )
        for r in RHOS
    ]
    if a.task == "stack":
        arms.append(("iid, shifted (z +0.35, gripper -0.3)", 0.0, shift))
    for label, rho, s in arms:
        res = arm(env, a.episodes, rho, s, fields["position"])
        lines.append(row(label, res, base))
        print(lines[-1], flush=True)
        if base is None:
            base = res["outcomes"]
        if res["effect"]:
            e = np.mean(res["effect"], axis=0)
            x, y, z = 1000 * e[fields["position"]]
            (width,) = 1000 * e[fields["gripper_width"]]
            effects.append(
                f"The shifted arm's chunks against the unshifted noise's at the same states (mean over "
                f"{len(res['effect'])} chunks): commanded height {z:+.1f} mm, gripper width "
                f"{width:+.1f} mm, planar position ({x:+.1f}, {y:+.1f}) mm."
            )
    lines += ["", *effects, "", f"{time.time() - started:.0f} s on one thread."]
    Path(a.out or HERE / f"noise-{a.task}.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
