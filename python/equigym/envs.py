"""Gymnasium environments over the Rust core.

Action: a 10-d absolute end-effector target per control step (20 Hz): TCP position (3, metres,
world frame), 6D rotation (6, the first two rows of the rotation matrix) and gripper width
(1, metres). ``action_mode="normalized"`` exposes the same action scaled to [-1, 1] (the
6D-rotation entries are already in [-1, 1] and pass through unchanged).

Observation: float32, laid out as the task's fields (see :attr:`EquiEnv.observation_fields`).
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces

from equigym import _core

#: gymnasium id -> Rust task id. Bump the version when physics, observations or rewards change.
ENV_IDS: dict[str, str] = {"EquiLift-v0": "lift", "EquiStack-v0": "stack", "EquiSquare-v0": "square"}

_ACTION_MODES = ("absolute", "normalized")


def physics_options(physics: dict[str, Any] | None, controller: str) -> dict[str, Any]:
    """The ``physics`` overrides with the arm ``controller`` (``"joint"`` or ``"cartesian"``) folded
    in; shared by the single, vector and latent-action envs."""
    if controller not in ("joint", "cartesian"):
        raise ValueError(f"controller must be 'joint' or 'cartesian', got {controller!r}")
    options = dict(physics or {})
    if controller == "cartesian":
        options["cartesian_control"] = True
    return options


class EquiEnv(gymnasium.Env):
    """One equigym task as a :class:`gymnasium.Env`.

    Args:
        task: Rust task id (``"lift"``, ``"stack"``, ``"square"``).
        render_mode: ``None`` or ``"rgb_array"``.
        reward: ``"sparse"`` (1 on success, else 0) or ``"dense"`` (shaped, in [0, 1]).
        action_mode: ``"absolute"`` (raw metres / 6D rotation) or ``"normalized"`` ([-1, 1]).
        joint_limits: enforce the arm's joint limits (turn off for symmetry ablations).
        urdf: path of a robot description to load instead of the shipped Panda.
        init_joint_noise: std of the noise added to the home joint configuration at reset.
        horizon: episode length in control steps (default: the task's).
        render_width, render_height: size of rendered images.
        physics: overrides of the physics settings (timestep, substeps, solver_iterations,
            friction, max_hand_force, max_hand_torque, max_finger_force, finger_speed,
            servo_time_constant).
        ranges: overrides of the initial-state ranges, name -> (low, high).
        variant: reset distribution, ``"D0"``, ``"D1"`` or ``"D2"`` (default: Stack D1,
            Square D2; Lift has only its own).
        controller: ``"joint"`` (default: IK, joint-space interpolation at the joints' speed
            limits) or ``"cartesian"`` (straight-line TCP paths; with ``joint_limits=False`` it
            commutes with rotations of the scene, which isolates the joint limits in symmetry
            ablations).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 20}

    def __init__(
        self,
        task: str = "lift",
        render_mode: str | None = None,
        reward: str = "sparse",
        action_mode: str = "absolute",
        joint_limits: bool = True,
        urdf: str | None = None,
        init_joint_noise: float = 0.02,
        horizon: int | None = None,
        render_width: int = 256,
        render_height: int = 256,
        physics: dict[str, float] | None = None,
        ranges: dict[str, tuple[float, float]] | None = None,
        variant: str | None = None,
        controller: str = "joint",
    ) -> None:
        physics = physics_options(physics, controller)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or one of {self.metadata['render_modes']}, got {render_mode!r}")
        if action_mode not in _ACTION_MODES:
            raise ValueError(f"action_mode must be one of {_ACTION_MODES}, got {action_mode!r}")
        if urdf is not None:
            urdf = str(urdf)
        self.core = _core.Env(
            task,
            reward=reward,
            urdf=urdf,
            joint_limits=joint_limits,
            init_joint_noise=init_joint_noise,
            horizon=horizon,
            physics=physics,
            ranges=ranges,
            variant=variant,
        )
        self.render_mode = render_mode
        self.action_mode = action_mode
        self.render_size = (int(render_width), int(render_height))
        self._low = self.core.action_low
        self._high = self.core.action_high
        dim = self.core.observation_dim
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(dim,), dtype=np.float32)
        if action_mode == "absolute":
            self.action_space = spaces.Box(self._low.astype(np.float32), self._high.astype(np.float32), dtype=np.float32)
        else:
            self.action_space = spaces.Box(-1.0, 1.0, shape=(10,), dtype=np.float32)
        self._needs_reset = True

    # -- metadata for agents and symmetry tools -------------------------------------------
    @property
    def observation_fields(self) -> dict[str, slice]:
        """Observation field name -> slice."""
        return {f["name"]: slice(f["start"], f["start"] + f["len"]) for f in self.core.observation_layout}

    @property
    def observation_layout(self) -> list[dict[str, Any]]:
        """Fields with their group representation (``rep``), as in the paper's tables."""
        return self.core.observation_layout

    @property
    def action_layout(self) -> list[dict[str, Any]]:
        return self.core.action_layout

    # -- gymnasium API ---------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        if seed is not None and (isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0):
            raise ValueError(f"seed must be None or a non-negative integer, got {seed!r}")
        super().reset(seed=seed)
        # The Rust episode seed comes from the gymnasium RNG: seeded resets are reproducible,
        # unseeded ones continue the stream.
        episode_seed = int(seed) if seed is not None else int(self.np_random.integers(0, 2**63 - 1))
        obs = self.core.reset(episode_seed)
        self._needs_reset = False
        info = {"episode_seed": episode_seed}
        return obs.astype(np.float32), info

    def step(self, action):
        action = self._to_absolute(action)
        obs, reward, terminated, truncated, info = self.core.step(action)
        return obs.astype(np.float32), float(reward), bool(terminated), bool(truncated), info

    def render(self):
        if self.render_mode is None:
            gymnasium.logger.warn("render() called without render_mode; pass render_mode='rgb_array' to make()")
            return None
        return self.core.render(*self.render_size)

    def close(self) -> None:
        pass

    # -- state -----------------------------------------------------------------------------
    def get_state(self) -> bytes:
        """The full simulator state; :meth:`set_state` restores it bit for bit."""
        return self.core.get_state()

    def set_state(self, state: bytes) -> None:
        if not isinstance(state, (bytes, bytearray, memoryview)):
            raise TypeError(f"state must be bytes from get_state(), got {type(state).__name__}")
        self.core.set_state(bytes(state))

    # -- helpers ---------------------------------------------------------------------------
    def _to_absolute(self, action) -> np.ndarray:
        a = np.asarray(action)
        if a.dtype.kind not in "fiu":
            raise TypeError(f"action must be a numeric array, got dtype {a.dtype}")
        if a.shape != (10,):
            raise ValueError(f"action must have shape (10,), got {a.shape}")
        a = a.astype(np.float64)
        if not np.all(np.isfinite(a)):
            raise ValueError(f"action contains NaN or infinity: {a}")
        if self.action_mode == "normalized":
            a = self._low + (np.clip(a, -1.0, 1.0) + 1.0) * 0.5 * (self._high - self._low)
        return np.ascontiguousarray(a)

    def normalize_action(self, absolute: np.ndarray) -> np.ndarray:
        """Map an absolute action to the normalized [-1, 1] space."""
        a = np.asarray(absolute, dtype=np.float64)
        return (2.0 * (a - self._low) / (self._high - self._low) - 1.0).astype(np.float32)


def register_envs() -> None:
    """Register every equigym id with gymnasium (idempotent)."""
    for env_id, task in ENV_IDS.items():
        if env_id in gymnasium.registry:
            continue
        gymnasium.register(
            id=env_id,
            entry_point="equigym.envs:EquiEnv",
            # gymnasium.make_vec(id, num_envs=B): B environments stepped in Rust (equigym.vector).
            vector_entry_point="equigym.vector:EquiVectorEnv",
            kwargs={"task": task},
            max_episode_steps=400,
        )
