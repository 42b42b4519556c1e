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
from equigym.errors import InvalidInputError

#: gymnasium id -> Rust task id. Bump the version when physics, observations or rewards change.
ENV_IDS: dict[str, str] = {"EquiLift-v0": "lift", "EquiStack-v0": "stack", "EquiSquare-v0": "square"}

ACTION_MODES = ("absolute", "normalized")

#: The environment options every equigym environment (single, vector, latent) takes as keyword
#: arguments. They are declared once, in Rust (``equigym_envs::EnvOptions``), and converted in
#: one function; this text is their documentation.
OPTIONS_DOC = """
        reward: ``"sparse"`` (1 on success, else 0; default) or ``"dense"`` (shaped, in [0, 1]).
        urdf: path of a robot description to load instead of the shipped Panda.
        joint_limits: enforce the arm's joint limits (default True; turn off for symmetry ablations).
        controller: ``"joint"`` (default: IK, joint-space interpolation at the joints' speed
            limits) or ``"cartesian"`` (straight-line TCP paths; with ``joint_limits=False`` it
            commutes with rotations of the scene, which isolates the joint limits in symmetry
            ablations).
        init_joint_noise: std of the noise added to the home joint configuration at reset
            (rad, default 0.02).
        horizon: episode length in control steps (default: the task's, 400); the environment
            truncates there itself.
        physics: overrides of the physics settings, any subset of the fields of
            ``equigym_envs::PhysicsConfig`` (``timestep``, ``substeps``, ``solver_iterations``,
            ``friction``, ...); an unknown name is an error.
        ranges: overrides of the initial-state ranges, name -> (low, high).
        variant: reset distribution, ``"D0"``, ``"D1"`` or ``"D2"`` (default: Stack D1,
            Square D2; Lift has only its own).
"""


def check_seed(seed: Any) -> None:
    """Seeds are None or non-negative integers (shared by every equigym environment)."""
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0):
        raise InvalidInputError(f"seed must be None or a non-negative integer, got {seed!r}")


def episode_seed(env: gymnasium.Env, seed: int | None) -> int:
    """The Rust episode seed of a reset: ``seed`` itself, or the next draw of the environment's
    gymnasium RNG (so that seeded resets are reproducible and unseeded ones continue the stream).
    Call after ``gymnasium.Env.reset(seed=seed)``."""
    return int(seed) if seed is not None else int(env.np_random.integers(0, 2**63 - 1))


def layout_slices(layout: list[dict[str, Any]]) -> dict[str, slice]:
    """Field name -> slice of one row, for a layout as ``EnvSpec`` gives it
    (``spec.observation_layout`` or ``spec.action_layout``)."""
    return {f["name"]: slice(f["start"], f["start"] + f["len"]) for f in layout}


class SpecLayouts:
    """The layout metadata of ``self.core.spec`` (one environment, or each row of a batch), for
    agents and symmetry tools."""

    core: Any

    @property
    def observation_fields(self) -> dict[str, slice]:
        """Observation field name -> slice (of one row)."""
        return layout_slices(self.core.spec.observation_layout)

    @property
    def observation_layout(self) -> list[dict[str, Any]]:
        """Fields with their group representation (``rep``), as in the paper's tables."""
        return self.core.spec.observation_layout

    @property
    def action_layout(self) -> list[dict[str, Any]]:
        return self.core.spec.action_layout


def action_box(spec: Any, action_mode: str) -> spaces.Box:
    """One environment's action space: the task's absolute bounds, or [-1, 1] when normalized."""
    if action_mode == "absolute":
        return spaces.Box(spec.action_low.astype(np.float32), spec.action_high.astype(np.float32), dtype=np.float32)
    return spaces.Box(-1.0, 1.0, shape=(spec.action_dim,), dtype=np.float32)


class CoreEnv(gymnasium.Env):
    """What every single equigym environment does the same way around its Rust ``core``: the
    horizon and seeded resets (float32 observations, ``info["episode_seed"]``)."""

    core: Any

    @property
    def horizon(self) -> int:
        """Episode length in primitive control steps (the environment truncates there)."""
        return self.core.horizon

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        check_seed(seed)
        super().reset(seed=seed)
        seed_used = episode_seed(self, seed)
        obs = self.core.reset(seed_used)
        return obs.astype(np.float32), {"episode_seed": seed_used}


class EquiEnv(SpecLayouts, CoreEnv):
    (
        """One equigym task as a :class:`gymnasium.Env` (``gymnasium.make("EquiLift-v0")``).

    Args:
        task: Rust task id (``"lift"``, ``"stack"``, ``"square"``).
        render_mode: ``None`` or ``"rgb_array"``.
        action_mode: ``"absolute"`` (raw metres / 6D rotation) or ``"normalized"`` ([-1, 1]).
        render_width, render_height: size of rendered images.
        **options: the environment options:
    """
        + OPTIONS_DOC
        + """
    Pickling and ``copy.deepcopy`` carry the full simulator state: a copy continues exactly as
    the original would.

    ## Version History
    * v0: Initial release (Lift, Stack D1, Square D2 on rapier3d with a Panda arm; 10-d absolute
      end-effector actions at 20 Hz; joint-space arm controller by default).
    """
    )

    metadata = {"render_modes": ["rgb_array"], "render_fps": 20}

    def __init__(
        self,
        task: str = "lift",
        render_mode: str | None = None,
        action_mode: str = "absolute",
        render_width: int = 256,
        render_height: int = 256,
        **options: Any,
    ) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise InvalidInputError(
                f"render_mode must be None or one of {self.metadata['render_modes']}, got {render_mode!r}"
            )
        if action_mode not in ACTION_MODES:
            raise InvalidInputError(f"action_mode must be one of {ACTION_MODES}, got {action_mode!r}")
        self.core = _core.Env(task, **options)
        self.render_mode = render_mode
        self.action_mode = action_mode
        self.render_size = (int(render_width), int(render_height))
        spec = self.core.spec
        self._low = spec.action_low
        self._high = spec.action_high
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(spec.observation_dim,), dtype=np.float32)
        self.action_space = action_box(spec, action_mode)

    # -- gymnasium API (reset: CoreEnv) ------------------------------------------------------
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
        if a.shape != self.action_space.shape:
            raise InvalidInputError(f"action must have shape {self.action_space.shape}, got {a.shape}")
        a = a.astype(np.float64)
        if not np.all(np.isfinite(a)):
            raise InvalidInputError(f"action contains NaN or infinity: {a}")
        if self.action_mode == "normalized":
            a = self._low + (np.clip(a, -1.0, 1.0) + 1.0) * 0.5 * (self._high - self._low)
        return np.ascontiguousarray(a)

    def normalize_action(self, absolute: np.ndarray) -> np.ndarray:
        """Map an absolute action to the normalized [-1, 1] space."""
        a = np.asarray(absolute, dtype=np.float64)
        return (2.0 * (a - self._low) / (self._high - self._low) - 1.0).astype(np.float32)


def register_envs() -> None:
    """Register every equigym id with gymnasium (idempotent).

    The ids are registered without ``max_episode_steps``: each environment truncates at its own
    ``horizon`` (400 control steps unless the ``horizon`` option says otherwise), so gymnasium's
    ``TimeLimit`` never cuts a longer horizon. ``gymnasium.make(id, max_episode_steps=n)`` still
    adds one.
    """
    for env_id, task in ENV_IDS.items():
        if env_id in gymnasium.registry:
            continue
        gymnasium.register(
            id=env_id,
            entry_point="equigym.envs:EquiEnv",
            # gymnasium.make_vec(id, num_envs=B): B environments stepped in Rust (equigym.vector).
            vector_entry_point="equigym.vector:EquiVectorEnv",
            kwargs={"task": task},
        )
