"""Where an episode's outcome turns: two rollouts from the same start that differ by float
rounding, side by side, on the shipped EDP and on the scripted expert.

    python docs/steering/study/stack-collapse/divergence.py [--task stack] [--starts 100]

- *EDP, dense vs Fourier kernel*: the base policy from start 10000 + k with the same noise
  stream (numpy ``default_rng(k)``, N(0, I) clipped to the bound) decoded by the runtime's two
  kernels, whose chunks differ only by float rounding on the same input.
- *Expert, clean vs perturbed*: the scripted expert from the same starts, one of the pair with
  every action moved by uniform noise of +-``--noise`` (1e-4, the size of the kernels' chunk
  differences) at every control step.

Per pair: how often the outcome differs, and when the observations first part by 1 mm and by
1 cm (largest absolute difference over the observation vector; control steps). Writes
``divergence-<task>.md`` beside this file.
"""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
THRESHOLDS = {"1 mm": 1e-3, "1 cm": 1e-2}
FIRST_START = 10_000


def note_parting(first: dict[str, int], a: np.ndarray, b: np.ndarray, step: int) -> None:
    """Record the control step at which two rollouts' observations first part by each gap."""
    gap = float(np.abs(a - b).max())
    for name, threshold in THRESHOLDS.items():
        if gap > threshold and name not in first:
            first[name] = step


def parted(first: dict[str, int], gap: str, episodes: int) -> str:
    """Episodes whose observations parted by ``gap``, and the median control step it happened."""
    steps = [s[gap] for s in first.values() if gap in s]
    if not steps:
        return f"0 of {episodes}"
    return f"{len(steps)} of {episodes} (step {statistics.median(steps):.0f})"


def edp_pair(task: str, starts: int) -> dict:
    from equigym import DiffusionPolicy, _core
    from equigym.assets import asset_path

    path = asset_path("edp", f"{task}.safetensors")
    policies = {k: DiffusionPolicy(path, kernel=k) for k in ("dense", "fourier")}
    variant = policies["dense"].metadata.get("variant") or None
    outcomes: dict[str, list[bool]] = {k: [] for k in policies}
    first: dict[int, dict[str, int]] = {}
    for k in range(starts):
        rng = np.random.default_rng(k)
        envs = {name: _core.LatentEnv(task, p, variant=variant) for name, p in policies.items()}
        for e in envs.values():
            e.reset(FIRST_START + k)
        ended: dict[str, bool] = {}
        first[k] = {}
        while len(ended) < len(envs):
            w = np.clip(rng.standard_normal(policies["dense"].action_dim), -1.5, 1.5)
            obs = {}
            for name, e in envs.items():
                if name in ended:
                    continue
                o, _, terminated, truncated, info = e.step(w)
                obs[name] = o
                if info["success"] or terminated or truncated:
                    ended[name] = bool(info["success"])
            if len(obs) == 2:
                note_parting(first[k], obs["dense"], obs["fourier"], envs["dense"].elapsed_steps)
        for name in envs:
            outcomes[name].append(ended[name])
    return {"label": "EDP, dense vs Fourier kernel", "a": outcomes["dense"], "b": outcomes["fourier"], "first": first}


def expert_pair(task: str, starts: int, noise: float) -> dict:
    from equigym import _core

    outcomes: dict[str, list[bool]] = {"clean": [], "perturbed": []}
    first: dict[int, dict[str, int]] = {}
    for k in range(starts):
        envs = {name: _core.Env(task) for name in outcomes}
        experts = {name: _core.Expert(task) for name in outcomes}
        for name in outcomes:
            envs[name].reset(FIRST_START + k)
            experts[name].reset(envs[name], FIRST_START + k)
        rng = np.random.default_rng(k)
        ended: dict[str, bool] = {}
        first[k] = {}
        for step in range(1, envs["clean"].horizon + 1):
            obs = {}
            for name, e in envs.items():
                if name in ended:
                    continue
                a = np.asarray(experts[name].act(e), dtype=np.float64)
                if name == "perturbed":
                    a = a + noise * rng.uniform(-1.0, 1.0, a.shape)
                o, _, terminated, truncated, info = e.step(a)
                obs[name] = o
                if info["success"] or terminated or truncated:
                    ended[name] = bool(info["success"])
            if len(obs) == 2:
                note_parting(first[k], obs["clean"], obs["perturbed"], step)
            if len(ended) == 2:
                break
        for name in outcomes:
            outcomes[name].append(ended.get(name, False))
    return {
        "label": f"scripted expert, clean vs every action +-{noise:g}",
        "a": outcomes["clean"],
        "b": outcomes["perturbed"],
        "first": first,
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", default="stack", choices=("lift", "stack", "square"))
    p.add_argument("--starts", type=int, default=100)
    p.add_argument("--noise", type=float, default=1e-4)
    p.add_argument("--out", default=None, help="default: divergence-<task>.md beside this file")
    a = p.parse_args()
    lines = [
        f"# Where an episode's outcome turns ({a.task})",
        "",
        f"`python docs/steering/study/stack-collapse/divergence.py --task {a.task} --starts {a.starts} "
        f"--noise {a.noise:g}`: pairs of rollouts from the same {a.starts} starts ({FIRST_START} + k). *Parted*: "
        "episodes whose observations came more than 1 mm / 1 cm apart while both ran, and the median control "
        "step when they did.",
        "",
        "| pair | success (first / second) | outcome differs | parted by 1 mm | parted by 1 cm |",
        "|---|---:|---:|---:|---:|",
    ]
    for pair in (edp_pair(a.task, a.starts), expert_pair(a.task, a.starts, a.noise)):
        n = len(pair["a"])
        differ = sum(x != y for x, y in zip(pair["a"], pair["b"]))
        lines.append(
            f"| {pair['label']} | {sum(pair['a'])} / {sum(pair['b'])} of {n} | {differ} of {n} | "
            f"{parted(pair['first'], '1 mm', n)} | {parted(pair['first'], '1 cm', n)} |"
        )
        print(lines[-1], flush=True)
    Path(a.out or HERE / f"divergence-{a.task}.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
