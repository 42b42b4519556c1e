"""Record scripted-expert demonstrations into HDF5, in robomimic's layout.

    python -m equigym.demos --task lift --episodes 3 --out data/lift_3.hdf5 [--variant D1]
        [--position-noise 0.002 --yaw-noise 0.05] [--keep-failures]
        [--execution-noise 0.01 --execution-noise-corr 0.9]

Two kinds of noise. ``--position-noise`` perturbs the expert's own command, and the perturbed
command is what is recorded (noisy demonstrations). ``--execution-noise`` is DART's (Laskey et
al., 2017): the env executes the expert's command plus AR(1) Gaussian noise on the position
(stationary std ``sigma``, step correlation ``corr``), and the clean command is recorded, so the
demos visit states off the expert's path and label them with the expert's correction.

Layout: ``data`` (attrs ``env_args`` = JSON with ``env_name``, ``env_kwargs``; ``total``), then
``data/demo_<i>`` (attrs ``num_samples``, ``seed``, ``success``) holding ``obs/<field>``
(float32, one dataset per observation field), ``actions`` (absolute 10-d actions as the env
takes them), ``rewards`` (sparse success), ``dones`` (1 at the last step). Episodes end at the
first successful step; only successful episodes are kept unless ``--keep-failures``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

from equigym import _core
from equigym._optional import require
from equigym.envs import ENV_IDS

TASK_ENV_IDS = {task: env_id for env_id, task in ENV_IDS.items()}


def _h5py() -> Any:
    return require("h5py", "recording demonstrations")


class ExecutionNoise:
    """DART's execution noise for one episode: AR(1) Gaussian offsets of the commanded position
    (stationary std ``std``, step correlation ``corr``), from the episode's own stream (the
    expert's is apart, in Rust). ``apply`` returns the action to execute; the clean one is what
    a demo records."""

    def __init__(self, episode_seed: int, std: float, corr: float) -> None:
        self.rng = np.random.default_rng([episode_seed, 0xDA27])
        self.std, self.corr = std, corr
        self.innovation = std * np.sqrt(1.0 - corr**2)
        self.offset = self.rng.normal(0.0, std, 3)

    def apply(self, action: Any) -> np.ndarray:
        executed = np.array(action, dtype=np.float64)
        if self.std > 0.0:
            executed[:3] += self.offset
            self.offset = self.corr * self.offset + self.rng.normal(0.0, self.innovation, 3)
        return executed


def record(
    task: str,
    episodes: int,
    out: str | Path,
    *,
    variant: str | None = None,
    position_noise: float = 0.0,
    yaw_noise: float = 0.0,
    seed: int = 0,
    keep_failures: bool = False,
    max_attempts: int | None = None,
    progress: bool = True,
    hold_steps: int = 0,
    execution_noise: float = 0.0,
    execution_noise_corr: float = 0.9,
    env_options: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Record ``episodes`` demonstrations (successful ones unless ``keep_failures``).

    Seeds ``seed, seed + 1, ...`` are tried until enough demos are kept (at most
    ``max_attempts``, default 3 x episodes). Returns a summary dict.

    An episode ends at its first successful step, or ``hold_steps`` expert steps after it (the
    expert keeps the object where it lifted it), so that a policy trained on the demos has seen
    what to do once the task is done: without them the policy leaves its data at success and
    drops what it lifted (docs/steering.md, "Steerability"). A demo counts as successful if it
    still succeeds at its last step. ``env_options`` are further keyword arguments of the
    environment (e.g. ``{"joint_limits": False}``), recorded in the file's ``env_args``.
    """
    if hold_steps < 0:
        raise ValueError(f"hold_steps must be >= 0, got {hold_steps}")
    if not (execution_noise >= 0.0 and 0.0 <= execution_noise_corr < 1.0):
        raise ValueError(
            f"execution_noise must be >= 0 and execution_noise_corr in [0, 1), got "
            f"{execution_noise}, {execution_noise_corr}"
        )
    h5py = _h5py()
    env_kwargs = {**({"variant": variant} if variant else {}), **(env_options or {})}
    env = _core.Env(task, **env_kwargs)
    expert = _core.Expert(task, position_noise=position_noise, yaw_noise=yaw_noise)
    fields = env.spec.observation_layout
    max_attempts = max_attempts or 3 * episodes
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    kept, tried, lengths = 0, 0, []
    try:
        from tqdm import tqdm

        bar = tqdm(total=episodes, desc=f"{task} demos", disable=not progress)
    except ImportError:  # pragma: no cover
        bar = None
    with h5py.File(out, "w") as f:
        data = f.create_group("data")
        data.attrs["env_args"] = json.dumps(
            {"env_name": TASK_ENV_IDS[task], "type": "equigym", "env_kwargs": env_kwargs}
        )
        data.attrs["expert"] = json.dumps(
            {
                "position_noise": position_noise,
                "yaw_noise": yaw_noise,
                "execution_noise": execution_noise,
                "execution_noise_corr": execution_noise_corr,
            }
        )
        while kept < episodes and tried < max_attempts:
            ep_seed = seed + tried
            tried += 1
            obs = [env.reset(ep_seed)]
            expert.reset(env, ep_seed)
            actions, rewards, success = [], [], False
            since_success = None
            noise = ExecutionNoise(ep_seed, execution_noise, execution_noise_corr)
            for _ in range(env.horizon):
                a = expert.act(env)
                o, r, _, truncated, info = env.step(noise.apply(a))
                actions.append(a)
                rewards.append(r)
                if info["success"] and since_success is None:
                    since_success = 0
                elif since_success is not None:
                    since_success += 1
                if (since_success is not None and since_success >= hold_steps) or truncated:
                    success = bool(info["success"])
                    break
                obs.append(o)
            if not success and not keep_failures:
                continue
            obs_arr = np.asarray(obs[: len(actions)])
            g = data.create_group(f"demo_{kept}")
            g.attrs["num_samples"] = len(actions)
            g.attrs["seed"] = ep_seed
            g.attrs["success"] = success
            og = g.create_group("obs")
            for field in fields:
                og.create_dataset(
                    field["name"], data=obs_arr[:, field["start"] : field["start"] + field["len"]].astype(np.float32)
                )
            g.create_dataset("actions", data=np.asarray(actions))
            g.create_dataset("rewards", data=np.asarray(rewards))
            dones = np.zeros(len(actions), dtype=np.int64)
            dones[-1] = 1
            g.create_dataset("dones", data=dones)
            lengths.append(len(actions))
            kept += 1
            if bar is not None:
                bar.update(1)
        data.attrs["total"] = int(sum(lengths))
    if bar is not None:
        bar.close()
    return {
        "task": task,
        "kept": kept,
        "tried": tried,
        "mean_length": float(np.mean(lengths)) if lengths else 0.0,
        "path": str(out),
    }


def load(path: str | Path) -> dict[str, Any]:
    """Read a demo file: ``{"env_args", "demos": [{"obs": (T, obs_dim), "actions": (T, 10), ...}]}``
    with observation fields concatenated in the task's layout order."""
    h5py = _h5py()
    with h5py.File(path, "r") as f:
        data = f["data"]
        env_args = json.loads(data.attrs["env_args"])
        task = ENV_IDS[env_args["env_name"]]
        order = [fd["name"] for fd in _core.TaskSymmetry(task).layout("observation")]
        demos = []
        for name in sorted(data.keys(), key=lambda k: int(k.split("_")[1])):
            g = data[name]
            obs = np.concatenate([np.asarray(g["obs"][k]) for k in order], axis=1)
            demos.append(
                {
                    "obs": obs,
                    "actions": np.asarray(g["actions"]),
                    "rewards": np.asarray(g["rewards"]),
                    "seed": int(g.attrs["seed"]),
                }
            )
    return {"env_args": env_args, "task": task, "demos": demos}


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", required=True, choices=sorted(TASK_ENV_IDS))
    p.add_argument("--episodes", type=int, required=True)
    p.add_argument("--out", required=True)
    p.add_argument("--variant", default=None)
    p.add_argument("--position-noise", type=float, default=0.0)
    p.add_argument("--yaw-noise", type=float, default=0.0)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--keep-failures", action="store_true")
    p.add_argument("--hold-steps", type=int, default=0, help="expert steps recorded after the first success")
    p.add_argument(
        "--execution-noise", type=float, default=0.0, help="DART: std (m) of AR(1) noise on the executed position"
    )
    p.add_argument("--env", default=None, help="further environment options as JSON, e.g. '{\"joint_limits\": false}'")
    p.add_argument("--execution-noise-corr", type=float, default=0.9, help="its correlation from step to step")
    a = p.parse_args(argv)
    summary = record(
        a.task,
        a.episodes,
        a.out,
        variant=a.variant,
        position_noise=a.position_noise,
        yaw_noise=a.yaw_noise,
        seed=a.seed,
        keep_failures=a.keep_failures,
        hold_steps=a.hold_steps,
        execution_noise=a.execution_noise,
        execution_noise_corr=a.execution_noise_corr,
        env_options=json.loads(a.env) if a.env else None,
    )
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
