"""Steer a diffusion policy with RL in the latent-noise MDP: DSRL, Equi-DSRL, Approx-Equi-DSRL
(and plain SAC on the raw action space), with evaluation, mean-Q logging, resumable checkpoints,
CSV logs and a report that writes the paper's Table 1 and plots.

    python -m baselines.steer run --method equi --task lift --seed 0 --steps 20000
    python -m baselines.steer base --task lift          # the base policy alone, N(0, I) noise
    python -m baselines.steer report --runs runs/steer --out docs/steering

Steps are primitive environment steps (a latent step runs a 4-action chunk). Hyperparameters are
DSRL's and the paper's (lr 3e-4, batch 256, tau 0.005, gamma 0.99 / 0.999 for Square, twin
critics, target entropy 0, entropy coefficient learned from 1.0, latent bound 1.5, warm-up with
N(0, I) noise, 4 envs) except the network width, the update-to-data ratio and the initial
entropy coefficient, which a preset sets: ``--preset cpu`` (default) uses 3 x 64 MLPs,
parameter-matched equivariant nets, UTD 4 and an initial entropy coefficient of 0.2 (from 1.0,
a 40-d latent's entropy bonus dominates the sparse reward for the first ~16k env steps, most of
a CPU budget; see docs/steering.md), sized so that Lift x 3 methods x 3 seeds x 16k env steps
finishes in under an hour on 2 cores
(escnn nets with matched parameters do ~8x the FLOPs of the MLPs: C8 regular fields expand
every weight into an 8 x 8 block); ``--preset paper`` uses 3 x 2048 and UTD 30 (Lift) / 20
(Square), which needs a GPU. A killed run resumes from its last checkpoint (model and replay
buffer) when started again with the same arguments; a larger ``--steps`` extends a finished run.
Sweeps over methods x tasks x seeds run as Ray Tune trials: ``python -m equigym.steer sweep --sb3
dsrl equi approx --methods`` (SB3 only; add Rust methods after ``--methods`` to run both sides).
"""

from __future__ import annotations

import argparse
import csv
import functools
import json
import time
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
import torch
from stable_baselines3 import SAC
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import DummyVecEnv

import equigym  # noqa: F401  (registers the ids)
from baselines.agents import EQUI_INITS, EquiSACPolicy, LayerNormSACPolicy, count_parameters
from equigym import _core
from equigym.latent import shipped_policy
from equigym.steer import EDP_KERNELS, UNNAMED_EDP_KERNEL, add_run_arguments
from equigym.wrappers import TerminateOnSuccess

METHODS = ("dsrl", "equi", "approx", "sac")
LATENT_IDS = {"lift": "EquiLift-Latent-v0", "stack": "EquiStack-Latent-v0", "square": "EquiSquare-Latent-v0"}
RAW_IDS = {"lift": "EquiLift-v0", "stack": "EquiStack-v0", "square": "EquiSquare-v0"}
#: The network and schedule presets, from their one home in the Rust agents (``Preset::named``).
PRESETS = {name: {k: v for k, v in _core.steer_preset(name).items() if v is not None} for name in ("cpu", "paper")}


class LatentSAC(SAC):
    """SAC whose warm-up draws the base policy's own noise, N(0, I) clipped to the latent bound,
    instead of uniform actions (DSRL)."""

    def _sample_action(self, learning_starts, action_noise=None, n_envs=1):
        if self.num_timesteps < learning_starts and isinstance(self.action_space, gymnasium.spaces.Box):
            high = self.action_space.high
            raw = np.clip(np.random.standard_normal((n_envs, *self.action_space.shape)), -high, high).astype(np.float32)
            return raw, self.policy.scale_action(raw)
        return super()._sample_action(learning_starts, action_noise, n_envs)


def load_policy(task: str, policy_file: str | None, edp_kernel: str | None) -> _core.DiffusionPolicy:
    """The EDP the latent envs run (the task's shipped one by default) on ``edp_kernel`` (default:
    the runtime's), loaded once and shared by every env of a run."""
    return _core.DiffusionPolicy(str(policy_file or shipped_policy(task)), kernel=edp_kernel)


@functools.cache
def equi_fields_matching(task: str, target: int, layers: int, residual: bool) -> int:
    """Hidden regular fields whose actor + critic parameter count is closest to ``target``.
    Cached: it builds escnn nets for every candidate, and a sweep trial rebuilds its agent at
    every evaluation interval."""
    obs_space = gymnasium.spaces.Box(-np.inf, np.inf, (equigym.Symmetry(task).dim("observation"),), np.float32)
    lat_space = gymnasium.spaces.Box(-1.5, 1.5, (40,), np.float32)
    best, best_gap = 8, None
    for fields in (8, 16, 24, 32, 48, 64, 96, 128, 192, 256):
        pol = EquiSACPolicy(
            obs_space, lat_space, lambda _: 3e-4, task=task, hidden_fields=fields, layers=layers, residual=residual
        )
        n = count_parameters(pol.actor) + count_parameters(pol.critic)
        gap = abs(n - target)
        if best_gap is None or gap < best_gap:
            best, best_gap = fields, gap
        if n > target:
            break
    return best


def build(
    method: str,
    task: str,
    preset: dict[str, Any],
    seed: int,
    joint_limits: bool,
    policy: _core.DiffusionPolicy | str | None,
    terminate_on_success: bool = False,
) -> tuple[SAC, Any]:
    """The agent and its env factory; ``policy`` is the latent envs' EDP (loaded, or a file; the
    shipped one on the default kernel where None)."""
    env_kwargs: dict[str, Any] = {"joint_limits": joint_limits}
    if method == "sac":
        env_id = RAW_IDS[task]
        env_kwargs.update(action_mode="normalized", reward="sparse")
    else:
        env_id = LATENT_IDS[task]
        if policy is not None:
            env_kwargs["policy"] = policy

    def make() -> gymnasium.Env:
        # The env truncates at its own horizon (400 control steps).
        return gymnasium.make(env_id, **env_kwargs)

    def make_train() -> gymnasium.Env:
        env = make()
        return TerminateOnSuccess(env) if terminate_on_success else env

    venv = DummyVecEnv([make_train for _ in range(preset["n_envs"])])
    venv.seed(seed)
    arch = [preset["width"]] * preset["layers"]
    common = dict(
        learning_rate=3e-4,
        buffer_size=1_000_000,
        batch_size=preset["batch"],
        tau=0.005,
        gamma=0.999 if task == "square" else 0.99,
        train_freq=1,
        gradient_steps=preset.get(f"utd_{task}", preset["utd"]) * preset["n_envs"],
        ent_coef=f"auto_{preset['ent_init']}",
        target_entropy=0.0,
        seed=seed,
        verbose=0,
        device="cpu",
    )
    if method in ("dsrl", "sac"):
        cls = LatentSAC if method == "dsrl" else SAC
        model = cls(
            LayerNormSACPolicy,
            venv,
            learning_starts=preset["warmup"],
            policy_kwargs=dict(net_arch=arch, activation_fn=torch.nn.Tanh),
            **common,
        )
    else:
        # Match the DSRL nets' parameter count (a policy alone, no model or replay buffer).
        dsrl = LayerNormSACPolicy(
            venv.observation_space, venv.action_space, lambda _: 3e-4, net_arch=arch, activation_fn=torch.nn.Tanh
        )
        target = count_parameters(dsrl.actor) + count_parameters(dsrl.critic)
        residual = method == "approx"
        fields = equi_fields_matching(task, target, preset["layers"], residual)
        model = LatentSAC(
            EquiSACPolicy,
            venv,
            learning_starts=preset["warmup"],
            policy_kwargs=dict(
                task=task,
                hidden_fields=fields,
                layers=preset["layers"],
                residual=residual,
                init=preset.get("equi_init", "escnn"),
            ),
            **common,
        )
    return model, make


def evaluate(model: SAC | None, make, episodes: int, seed: int = 10_000) -> float:
    """Success rate over seeded episodes (success if any step succeeds) of the stochastic actor,
    or, with ``model=None``, of the base policy alone: latent noise N(0, I) clipped to the bound."""
    env = make()
    if model is not None:
        model.policy.set_training_mode(False)
    rng = np.random.default_rng(seed)
    high = env.action_space.high
    wins = 0
    for k in range(episodes):
        obs, _ = env.reset(seed=seed + k)
        done, success = False, False
        while not done:
            if model is None:
                action = np.clip(rng.standard_normal(env.action_space.shape), -high, high).astype(np.float32)
            else:
                action, _ = model.predict(obs, deterministic=False)
            obs, _, term, trunc, info = env.step(action)
            success |= bool(info.get("success", False))
            done = term or trunc or success
        wins += success
    return wins / episodes


def base_success(
    task: str,
    out: str | Path,
    episodes: int = 100,
    joint_limits: bool = True,
    policy_file: str | None = None,
    edp_kernel: str | None = None,
) -> float:
    """The base policy's success before steering (cached in <out>/<task>[-nolimits]/base.json)."""
    path = Path(out) / f"{task}{'' if joint_limits else '-nolimits'}" / "base.json"
    policy = load_policy(task, policy_file, edp_kernel)
    if path.exists():
        data = json.loads(path.read_text())
        same = data.get("episodes") == episodes and data.get("policy") == policy_file
        if same and data.get("edp_kernel", UNNAMED_EDP_KERNEL) == policy.kernel:
            return float(data["success_rate"])
    kwargs: dict[str, Any] = {"joint_limits": joint_limits, "policy": policy}
    rate = evaluate(None, lambda: gymnasium.make(LATENT_IDS[task], **kwargs), episodes)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(
        json.dumps(
            {
                "task": task,
                "joint_limits": joint_limits,
                "episodes": episodes,
                "policy": policy_file,
                "edp_kernel": policy.kernel,
                "success_rate": rate,
            }
        )
    )
    return rate


def mean_q(model: SAC, batch: int = 256) -> float:
    if model.replay_buffer is None or model.replay_buffer.size() == 0:
        return float("nan")
    data = model.replay_buffer.sample(min(batch, model.replay_buffer.size()))
    with torch.no_grad():
        qs = model.critic(data.observations, data.actions)
    return float(torch.min(torch.cat(qs, dim=1), dim=1).values.mean())


TRAIN_COLUMNS = ["env_steps", "alpha", "entropy", "edge_fraction", "critic_loss", "target_q", "policy_q"]
EDGE = 0.99  # a latent coordinate (or a rho1 pair's radius) beyond this is at the edge of the box


def diagnostics(model: SAC, batch: int = 256) -> dict[str, float]:
    """The learner's state on a replay sample, as the Rust agents' ``train.csv`` records it:
    entropy coefficient, policy entropy, fraction of latent coordinates at the edge of the box,
    SB3's critic loss against the soft target, mean target, mean Q at the actor's own actions.
    The global numpy and torch random states are restored afterwards, so that recording them
    does not change the run."""
    nan = {k: float("nan") for k in TRAIN_COLUMNS[1:]}
    if model.replay_buffer is None or model.replay_buffer.size() == 0:
        return nan
    np_state, torch_state = np.random.get_state(), torch.get_rng_state()
    try:
        data = model.replay_buffer.sample(min(batch, model.replay_buffer.size()))
        with torch.no_grad():
            alpha = (
                float(torch.exp(model.log_ent_coef.detach()))
                if model.log_ent_coef is not None
                else float(model.ent_coef_tensor)
            )
            a, logp = model.actor.action_log_prob(data.observations)
            a2, logp2 = model.actor.action_log_prob(data.next_observations)
            next_q = torch.min(torch.cat(model.critic_target(data.next_observations, a2), dim=1), dim=1).values
            y = data.rewards.flatten() + (1 - data.dones.flatten()) * model.gamma * (next_q - alpha * logp2.flatten())
            qs = model.critic(data.observations, data.actions)
            critic_loss = 0.5 * sum(float(torch.mean((q.flatten() - y) ** 2)) for q in qs)
            policy_q = torch.min(torch.cat(model.critic(data.observations, a), dim=1), dim=1).values
            pairs = getattr(model.actor, "pairs", None)
            if pairs is not None and len(pairs):
                singles = model.actor.singles
                edge = 2 * int((a[:, pairs].norm(dim=-1) > EDGE).sum()) + int((a[:, singles].abs() > EDGE).sum())
            else:
                edge = int((a.abs() > EDGE).sum())
        return {
            "alpha": alpha,
            "entropy": float(-logp.mean()),
            "edge_fraction": edge / a.numel(),
            "critic_loss": critic_loss,
            "target_q": float(y.mean()),
            "policy_q": float(policy_q.mean()),
        }
    finally:
        np.random.set_state(np_state)
        torch.set_rng_state(torch_state)


class EvalLogger(BaseCallback):
    def __init__(
        self, make, log_path: Path, ckpt: Path, every: int, episodes: int, chunk: int, total: int, progress: bool
    ):
        super().__init__()
        self.make, self.log_path, self.ckpt, self.every, self.episodes = make, log_path, ckpt, every, episodes
        # A resumed run continues its log: its clock and its evaluation schedule (a run resumed
        # from the checkpoint of the evaluation at step S must not evaluate at S again).
        rows = list(csv.reader(log_path.read_text().splitlines()))[1:] if log_path.exists() else []
        self.last_logged = int(rows[-1][0]) if rows else None
        self.chunk, self.total, self.t0 = chunk, total, time.time() - (float(rows[-1][3]) if rows else 0.0)
        self.next_eval = 0
        self.bar = None
        if progress:
            from tqdm import tqdm

            self.bar = tqdm(total=total, desc=log_path.parent.name, unit="step")

    def env_steps(self) -> int:
        return self.model.num_timesteps * self.chunk

    def _on_training_start(self) -> None:
        self.next_eval = (self.env_steps() // self.every) * self.every
        if self.last_logged is not None and self.last_logged >= self.next_eval:
            self.next_eval = (self.last_logged // self.every + 1) * self.every
        if self.bar is not None:
            self.bar.update(self.env_steps())

    def _on_step(self) -> bool:
        steps = self.env_steps()
        if self.bar is not None:
            self.bar.update(self.model.n_envs * self.chunk)
        if steps >= self.next_eval:
            self.next_eval += self.every
            rate = evaluate(self.model, self.make, self.episodes)
            new = not self.log_path.exists()
            with open(self.log_path, "a", newline="") as f:
                w = csv.writer(f)
                if new:
                    w.writerow(["env_steps", "success_rate", "mean_q", "seconds"])
                w.writerow([steps, rate, mean_q(self.model), round(time.time() - self.t0, 1)])
            train_log = self.log_path.with_name("train.csv")
            new = not train_log.exists()
            with open(train_log, "a", newline="") as f:
                w = csv.writer(f)
                if new:
                    w.writerow(TRAIN_COLUMNS)
                d = diagnostics(self.model)
                w.writerow([steps] + [d[k] for k in TRAIN_COLUMNS[1:]])
            self.model.save(self.ckpt / "model.zip")
            self.model.save_replay_buffer(self.ckpt / "replay.pkl")
        return steps < self.total


def run(
    method: str,
    task: str,
    seed: int,
    steps: int,
    out: str | Path,
    preset: str | dict[str, Any] = "cpu",
    joint_limits: bool = True,
    eval_every: int = 2000,
    eval_episodes: int = 50,
    policy_file: str | None = None,
    progress: bool = True,
    terminate_on_success: bool = False,
    edp_kernel: str | None = None,
) -> Path:
    if isinstance(preset, str):
        preset = {"name": preset, **PRESETS[preset]}
    name = f"{task}{'' if joint_limits else '-nolimits'}/{method}/seed{seed}"
    run_dir = Path(out) / name
    ckpt = run_dir / "checkpoint"
    ckpt.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(1)
    policy = None if method == "sac" else load_policy(task, policy_file, edp_kernel)
    model, make = build(method, task, preset, seed, joint_limits, policy, terminate_on_success)
    chunk = 1 if method == "sac" else 4
    meta = {
        "agent": "sb3",
        "method": method,
        "task": task,
        "seed": seed,
        # the EDP and the evaluation protocol, as the Rust runner records them: the control arms
        # (equigym.steer.controls) are evaluated from these
        "policy": str(policy_file) if policy_file else str(shipped_policy(task)),
        "eval_every": eval_every,
        "eval_episodes": eval_episodes,
        "preset": preset,
        "steps": steps,
        "joint_limits": joint_limits,
        **({"terminate_on_success": True} if terminate_on_success else {}),
        # named where not dense, as the Rust runner does (runs recorded before the Fourier kernel
        # name none)
        **({"edp_kernel": policy.kernel} if policy and policy.kernel != UNNAMED_EDP_KERNEL else {}),
        "params_actor": count_parameters(model.actor),
        "params_critic": count_parameters(model.critic),
    }
    if (ckpt / "model.zip").exists():
        model = model.__class__.load(ckpt / "model.zip", env=model.get_env(), device="cpu")
        model.load_replay_buffer(ckpt / "replay.pkl")
    else:  # logs of an older run without a checkpoint would mix two runs
        for stale in ("log.csv", "train.csv", "summary.json"):
            (run_dir / stale).unlink(missing_ok=True)
    (run_dir / "run.json").write_text(json.dumps(meta, indent=1))
    print(json.dumps(meta))
    cb = EvalLogger(make, run_dir / "log.csv", ckpt, eval_every, eval_episodes, chunk, steps, progress)
    remaining = max(0, steps // chunk - model.num_timesteps)
    if remaining:
        model.learn(total_timesteps=remaining + model.n_envs, callback=cb, reset_num_timesteps=False)
    if cb.bar is not None:
        cb.bar.close()
    # The run directory's layout is the Rust runner's (equigym.steer.runs): summary.json says how
    # far the run got and its clock, so that a sweep or the study can tell a finished run.
    summary = {"agent": "sb3", "env_steps": model.num_timesteps * chunk, "seconds": round(time.time() - cb.t0, 1)}
    (run_dir / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
    return run_dir


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("run")
    s.add_argument("--method", choices=METHODS, required=True)
    s.add_argument("--task", default="lift", choices=sorted(LATENT_IDS))
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--no-progress", action="store_true")
    s.add_argument("--steps", type=int, default=20_000, help="primitive environment steps per run")
    s.add_argument("--out", default="runs/steer")
    s.add_argument("--preset", choices=sorted(PRESETS), default="cpu")
    s.add_argument("--ent-init", type=float, default=None, help="initial entropy coefficient (default: the preset's)")
    s.add_argument(
        "--equi-init",
        choices=EQUI_INITS,
        default=None,
        help="equivariant layers' initialisation: escnn's (default) or scaled to PyTorch's default RMS",
    )
    add_run_arguments(s)
    b = sub.add_parser("base", help="success of the base policy alone (latent noise N(0, I))")
    b.add_argument("--task", default="lift", choices=sorted(LATENT_IDS))
    b.add_argument("--episodes", type=int, default=100)
    b.add_argument("--out", default="runs/steer")
    b.add_argument("--no-joint-limits", action="store_true")
    b.add_argument("--policy", default=None)
    b.add_argument("--edp-kernel", choices=EDP_KERNELS, default=None)
    r = sub.add_parser("report")
    r.add_argument("--runs", default="runs/steer")
    r.add_argument("--out", default="docs/steering")
    a = p.parse_args(argv)
    if a.cmd == "report":
        from equigym.steer.sweep_report import write_report

        print(write_report(a.runs, a.out))
    elif a.cmd == "base":
        print(
            f"{a.task}: base policy success "
            f"{base_success(a.task, a.out, a.episodes, not a.no_joint_limits, a.policy, a.edp_kernel):.3f}"
        )
    else:
        preset = {"name": a.preset, **PRESETS[a.preset]}
        if a.ent_init is not None:
            preset["ent_init"] = a.ent_init
        if a.equi_init is not None:
            preset["equi_init"] = a.equi_init
        run(
            a.method,
            a.task,
            a.seed,
            a.steps,
            a.out,
            preset,
            not a.no_joint_limits,
            a.eval_every,
            a.eval_episodes,
            a.policy,
            progress=not a.no_progress,
            terminate_on_success=a.terminate_on_success,
            edp_kernel=a.edp_kernel,
        )


if __name__ == "__main__":
    main()
