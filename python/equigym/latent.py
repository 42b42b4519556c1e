"""Latent-action environments (DSRL's latent-noise MDP) over a shipped or user diffusion policy.

The action is the diffusion policy's initial noise w (the action chunk's layout, bounded to
[-bound, bound], default 1.5); each step denoises w once from the current observation with
deterministic DDIM (in Rust), runs the chunk of absolute actions and returns the summed reward
(success - 1 per primitive step, in {-chunk_len, ..., 0}). Episodes truncate at the task's
horizon (counted in primitive steps), never at success. ``info["executed"]`` gives the primitive
steps, so agents can count environment steps as DSRL does.

>>> env = gymnasium.make("EquiLift-Latent-v0")            # the shipped Lift EDP
>>> env = gymnasium.make("EquiLift-Latent-v0", policy="my_edp.safetensors", joint_limits=False)
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces
from gymnasium.vector.utils import batch_space

from equigym import _core
from equigym.assets import policy_path
from equigym.envs import OPTIONS_DOC, CoreEnv
from equigym.errors import InvalidInputError
from equigym.vector import NativeVectorEnv, _mode_name, check_vector_args, vector_horizon

#: gymnasium id -> task id.
LATENT_ENV_IDS: dict[str, str] = {
    "EquiLift-Latent-v0": "lift",
    "EquiStack-Latent-v0": "stack",
    "EquiSquare-Latent-v0": "square",
}


def shipped_policy(task: str) -> Path:
    """Path of the EDP shipped for ``task`` (:func:`equigym.assets.policy_path`)."""
    return policy_path(task)


def _policy_arg(task: str, policy: Any) -> Any:
    """The ``policy`` argument as Rust takes it: the shipped file by default, paths as strings."""
    if policy is None:
        policy = shipped_policy(task)
    return str(policy) if isinstance(policy, Path) else policy


class EquiLatentEnv(CoreEnv):
    (
        """A task whose action is the latent noise of an (equivariant) diffusion policy
    (``gymnasium.make("EquiLift-Latent-v0")``).

    Args:
        task: task id.
        policy: a ``.safetensors`` file from ``baselines.edp`` or a loaded
            :class:`equigym._core.DiffusionPolicy` (shared between envs); default: the shipped one.
        bound: latent bound (actions are clipped to [-bound, bound]).
        ddim_steps: denoising steps (default: the policy's, 5).
        **options: the environment options of :class:`equigym.EquiEnv` (``reward`` must stay sparse:
            the latent env returns success - 1 per primitive step):
    """
        + OPTIONS_DOC
        + """
    Pickling and ``copy.deepcopy`` carry the policy (its bytes) and the full simulator state.

    ## Version History
    * v0: Initial release (C8-equivariant EDPs shipped for Lift, Stack D1 and Square D2;
      chunks of 4 absolute actions; deterministic DDIM with 5 steps).
    """
    )

    metadata = {"render_modes": [], "render_fps": 5}

    def __init__(
        self,
        task: str = "lift",
        policy: Any = None,
        bound: float = 1.5,
        ddim_steps: int | None = None,
        **options: Any,
    ) -> None:
        policy = _policy_arg(task, policy)
        self.core = _core.LatentEnv(task, policy, bound=bound, ddim_steps=ddim_steps, **options)
        dim = self.core.latent_dim
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(self.core.observation_dim,), dtype=np.float32)
        self.action_space = spaces.Box(-bound, bound, shape=(dim,), dtype=np.float32)
        self.chunk_len = self.core.chunk_len

    def step(self, action):
        w = np.asarray(action)
        if w.dtype.kind not in "fiu":
            raise TypeError(f"latent action must be numeric, got dtype {w.dtype}")
        if w.shape != self.action_space.shape:
            raise InvalidInputError(f"latent action must have shape {self.action_space.shape}, got {w.shape}")
        obs, reward, terminated, truncated, info = self.core.step(np.ascontiguousarray(w, dtype=np.float64))
        return obs.astype(np.float32), float(reward), bool(terminated), bool(truncated), info

    def decode(self, action) -> np.ndarray:
        """The (chunk_len, 10) absolute actions the policy makes of ``action`` now."""
        return self.core.decode(np.ascontiguousarray(action, dtype=np.float64)).reshape(self.chunk_len, 10)

    def get_state(self) -> bytes:
        return self.core.get_state()

    def set_state(self, state: bytes) -> None:
        self.core.set_state(bytes(state))


class EquiLatentVectorEnv(NativeVectorEnv):
    """B latent-action environments as one :class:`gymnasium.vector.VectorEnv`
    (``gymnasium.make_vec("EquiLift-Latent-v0", num_envs=B)``).

    One ``step`` is one call into Rust: the B latent actions are denoised together (one batched
    DDIM, rows split across the thread pool), then the B chunks run in parallel. Each row's
    chunk is bit for bit what a single :class:`EquiLatentEnv` makes of it, so a vector env and B
    single envs with the same seeds and latent actions give the same rollouts. Auto-reset,
    seeding and ``reset_mask`` are those of :class:`equigym.vector.EquiVectorEnv`;
    ``info["executed"]`` gives the primitive steps each sub-environment ran.

    Args: ``task``, ``num_envs``, ``threads`` (0: one per core), ``autoreset_mode``, the
    arguments of :class:`EquiLatentEnv` (``policy``, ``bound``, ``ddim_steps``) and the
    environment options (``controller``, ``joint_limits``, ...). ``max_episode_steps`` caps the
    horizon (primitive steps).

    ## Version History
    * v0: Initial release.
    """

    def __init__(
        self,
        task: str = "lift",
        num_envs: int = 1,
        *,
        policy: Any = None,
        bound: float = 1.5,
        ddim_steps: int | None = None,
        threads: int = 0,
        autoreset_mode: Any = "next_step",
        max_episode_steps: int | None = None,
        render_mode: str | None = None,
        **options: Any,
    ) -> None:
        if render_mode is not None:
            raise InvalidInputError("latent vector environments do not render")
        check_vector_args(num_envs, threads)
        mode = _mode_name(autoreset_mode)
        vector_horizon(options, max_episode_steps)
        policy = _policy_arg(task, policy)
        self.core = _core.LatentVecEnv(
            task,
            policy,
            int(num_envs),
            threads=int(threads),
            autoreset_mode=mode,
            bound=bound,
            ddim_steps=ddim_steps,
            **options,
        )
        self._init_batch(num_envs, mode)
        self.chunk_len = self.core.chunk_len
        dim = self.core.latent_dim
        self.single_observation_space = spaces.Box(
            -np.inf, np.inf, shape=(self.core.observation_dim,), dtype=np.float32
        )
        self.single_action_space = spaces.Box(-bound, bound, shape=(dim,), dtype=np.float32)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)

    def _to_core(self, a: np.ndarray) -> np.ndarray:
        if a.shape != self.action_space.shape:
            raise InvalidInputError(f"latent actions must have shape {self.action_space.shape}, got {a.shape}")
        return np.ascontiguousarray(a, dtype=np.float64)

    def _step_info(self, infos: dict[str, Any]) -> None:
        infos["executed"] = self.core.executed()
        infos["_executed"] = self._all

    def last_chunks(self) -> np.ndarray:
        """The (B, chunk_len, 10) absolute actions the last step executed."""
        return self.core.last_chunks().reshape(self.num_envs, self.chunk_len, 10)


def register_latent_envs() -> None:
    for env_id, task in LATENT_ENV_IDS.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(
                id=env_id,
                entry_point="equigym.latent:EquiLatentEnv",
                vector_entry_point="equigym.latent:EquiLatentVectorEnv",
                kwargs={"task": task},
            )
