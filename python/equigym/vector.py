"""Native vector environments: B equigym environments stepped in Rust per call.

>>> import gymnasium, equigym
>>> envs = gymnasium.make_vec("EquiLift-v0", num_envs=16)          # threads: all cores
>>> obs, info = envs.reset(seed=0)                                   # sub-env i gets seed 0 + i
>>> obs, rewards, terminated, truncated, info = envs.step(envs.action_space.sample())

One ``step`` is one call into Rust with all B actions as one array; the environments step in
parallel on a Rust thread pool (``threads=...``) with the GIL released, and observations,
rewards and flags come back as arrays. No Python code runs per sub-environment.

Auto-reset (``metadata["autoreset_mode"]``) follows gymnasium 1.x:

- ``NEXT_STEP`` (default): the step on which an episode ends returns its last observation with
  ``terminated`` or ``truncated`` set; the next ``step`` ignores that sub-environment's action,
  resets it and returns its reset observation with reward 0 and both flags False.
- ``SAME_STEP`` (``autoreset_mode="same_step"``): the step on which an episode ends returns the
  reset observation; the last observation of the ended episode is in ``info["final_obs"]``
  (masked by ``info["_final_obs"]``) and its step info in ``info["final_info"]``.

Episodes are truncated at the horizon (400 control steps, or the ``horizon`` option, or
``max_episode_steps`` when smaller) inside the vector environment; gymnasium's ``TimeLimit``
does not wrap vector environments.

Seeds: ``reset(seed=s)`` seeds sub-environment ``i`` with ``s + i`` (as gymnasium's
``SyncVectorEnv`` does), ``reset(seed=[s0, s1, ...])`` with ``s_i``; the first episode then
equals ``gymnasium.make(id).reset(seed=s_i)`` bit for bit under the same actions. Automatic
resets draw their episode seeds from a per-sub-environment stream seeded with ``s_i``;
``info["episode_seed"]`` (on reset and on every auto-reset) says which seed each episode got.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces
from gymnasium.vector import VectorEnv
from gymnasium.vector.utils import batch_space

from equigym import _core
from equigym.envs import ACTION_MODES, OPTIONS_DOC, SpecLayouts, action_box
from equigym.errors import InvalidInputError

try:  # gymnasium >= 1.1
    from gymnasium.vector import AutoresetMode
except ImportError:  # pragma: no cover - gymnasium 1.0 only knows next-step autoreset
    AutoresetMode = None

_MODES = {"next_step": "NextStep", "same_step": "SameStep"}


def _mode_name(mode: Any) -> str:
    """'next_step' / 'same_step' from a string or a gymnasium AutoresetMode."""
    if AutoresetMode is not None and isinstance(mode, AutoresetMode):
        mode = mode.value
    if isinstance(mode, str):
        key = mode.lower().replace("-", "_")
        for name, value in _MODES.items():
            if key in (name, value.lower()):
                return name
    raise InvalidInputError(
        f"autoreset_mode must be 'next_step' or 'same_step' (or a gymnasium AutoresetMode), got {mode!r}"
    )


class NativeVectorEnv(VectorEnv):
    """What every equigym vector environment shares: a Rust batch in ``self.core`` (``reset``,
    ``step``, ``episode_seeds``), seeding, ``reset_mask`` and the info dictionaries. Subclasses
    build the core and the spaces and say how actions reach Rust (:meth:`_to_core`)."""

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP if AutoresetMode else "NextStep"}
    render_mode = None
    core: Any

    def _init_batch(self, num_envs: int, mode: str) -> None:
        self.num_envs = int(num_envs)
        self.metadata = {"autoreset_mode": AutoresetMode(_MODES[mode]) if AutoresetMode else _MODES[mode]}
        self._all = np.ones(self.num_envs, dtype=bool)
        self._needs_reset = True

    @property
    def threads(self) -> int:
        """Threads of the Rust pool that steps the sub-environments."""
        return self.core.threads

    @property
    def autoreset_mode(self) -> str:
        """``"next_step"`` or ``"same_step"``."""
        return self.core.autoreset_mode

    @property
    def horizon(self) -> int:
        """Episode length of every sub-environment, in (primitive) control steps."""
        return self.core.horizon

    def episode_seeds(self) -> np.ndarray:
        """Seed of each sub-environment's current episode (a single env's ``reset(seed)`` replays it)."""
        return self.core.episode_seeds()

    def reset(self, *, seed: int | Sequence[int] | None = None, options: dict[str, Any] | None = None):
        n = self.num_envs
        if seed is None:
            seeds = self.np_random.integers(0, 2**63 - 1, size=n, dtype=np.int64).tolist()
        elif isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
            if seed < 0:
                raise InvalidInputError(f"seed must be None, a non-negative integer or a list of them, got {seed!r}")
            super().reset(seed=int(seed))
            seeds = [int(seed) + i for i in range(n)]
        else:
            try:
                seeds = list(seed)
            except TypeError:
                seeds = []
            if len(seeds) != n or any(
                isinstance(s, bool) or not isinstance(s, (int, np.integer)) or s < 0 for s in seeds
            ):
                raise InvalidInputError(
                    f"seed must be None, a non-negative integer or a list of {n} of them, got {seed!r}"
                )
            seeds = [int(s) for s in seeds]
        mask = None
        if options and "reset_mask" in options:
            mask = np.asarray(options["reset_mask"])
            if mask.shape != (n,) or mask.dtype != np.bool_ or not mask.any():
                raise InvalidInputError(f"options['reset_mask'] must be a bool array of shape ({n},) with a True value")
            if self._needs_reset and not mask.all():
                raise InvalidInputError("the first reset must reset every sub-environment (no reset_mask)")
            mask = mask.tolist()
        obs = self.core.reset(seeds, mask)
        self._needs_reset = False
        reset = self._all if mask is None else np.asarray(mask)
        return obs, {"episode_seed": self.core.episode_seeds(), "_episode_seed": reset.copy()}

    def _to_core(self, actions: Any) -> np.ndarray:
        """Check the batch of actions and convert it to the C-contiguous float64 array Rust takes."""
        raise NotImplementedError

    def _step_info(self, infos: dict[str, Any]) -> None:
        """Add subclass-specific entries to a step's info dictionary."""

    def step(self, actions):
        if self._needs_reset:
            raise gymnasium.error.ResetNeeded("Cannot call step() before reset()")
        a = np.asarray(actions)
        if a.dtype.kind not in "fiu":
            raise TypeError(f"actions must be a numeric array, got dtype {a.dtype}")
        a = self._to_core(a)
        # NaN / infinity is rejected in Rust (ValueError naming the sub-environment) before anything steps.
        obs, rewards, terminated, truncated, success, reset, final_obs = self.core.step(a)
        infos: dict[str, Any] = {
            "success": success,
            "_success": self._all,
            "is_success": success,
            "_is_success": self._all,
        }
        self._step_info(infos)
        if reset.any():
            infos["episode_seed"] = self.core.episode_seeds()
            infos["_episode_seed"] = reset
            if final_obs is not None:
                # same_step: the ended episodes' last observations and step infos.
                infos["final_obs"] = final_obs
                infos["_final_obs"] = reset
                infos["final_info"] = {
                    "success": success,
                    "_success": reset,
                    "is_success": success,
                    "_is_success": reset,
                }
                infos["_final_info"] = reset
        return obs, rewards, terminated, truncated, infos

    def close_extras(self, **kwargs: Any) -> None:
        pass


def vector_horizon(options: dict[str, Any], max_episode_steps: int | None) -> None:
    """Fold ``max_episode_steps`` (what ``gymnasium.make_vec`` passes) into the ``horizon``
    option: the smaller of the two applies."""
    if max_episode_steps is not None:
        h = options.get("horizon")
        options["horizon"] = max_episode_steps if h is None else min(h, max_episode_steps)


def check_vector_args(num_envs: Any, threads: Any) -> None:
    if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
        raise InvalidInputError(f"num_envs must be a positive integer, got {num_envs!r}")
    if isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or threads < 0:
        raise InvalidInputError(f"threads must be a non-negative integer (0: one per core), got {threads!r}")


class EquiVectorEnv(SpecLayouts, NativeVectorEnv):
    (
        """``num_envs`` copies of one equigym task as a :class:`gymnasium.vector.VectorEnv`.

    Args:
        task: Rust task id (``"lift"``, ``"stack"``, ``"square"``).
        num_envs: number of sub-environments B.
        threads: size of the Rust thread pool (0: one thread per core).
        autoreset_mode: ``"next_step"`` (default) or ``"same_step"``, or a ``gymnasium.vector.AutoresetMode``.
        max_episode_steps: truncation horizon; the smaller of this and ``horizon`` applies.
        action_mode: as for :class:`equigym.EquiEnv`.
        **options: the environment options of :class:`equigym.EquiEnv`:
    """
        + OPTIONS_DOC
        + """
    ## Version History
    * v0: Initial release.
    """
    )

    def __init__(
        self,
        task: str = "lift",
        num_envs: int = 1,
        *,
        threads: int = 0,
        autoreset_mode: Any = "next_step",
        max_episode_steps: int | None = None,
        render_mode: str | None = None,
        action_mode: str = "absolute",
        **options: Any,
    ) -> None:
        if render_mode is not None:
            raise InvalidInputError(
                "EquiVectorEnv does not render; use gymnasium.make(id, render_mode='rgb_array') per env"
            )
        if action_mode not in ACTION_MODES:
            raise InvalidInputError(f"action_mode must be one of {ACTION_MODES}, got {action_mode!r}")
        check_vector_args(num_envs, threads)
        mode = _mode_name(autoreset_mode)
        vector_horizon(options, max_episode_steps)
        self.core = _core.VecEnv(task, int(num_envs), threads=int(threads), autoreset_mode=mode, **options)
        self._init_batch(num_envs, mode)
        self.action_mode = action_mode
        spec = self.core.spec
        self._low = spec.action_low
        self._high = spec.action_high
        self._scale = 0.5 * (self._high - self._low)
        self.single_observation_space = spaces.Box(-np.inf, np.inf, shape=(spec.observation_dim,), dtype=np.float32)
        self.single_action_space = action_box(spec, action_mode)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)

    # -- gymnasium API ---------------------------------------------------------------------
    def _to_core(self, a: np.ndarray) -> np.ndarray:
        if a.shape != self.action_space.shape:
            raise InvalidInputError(f"actions must have shape {self.action_space.shape}, got {a.shape}")
        if self.action_mode == "normalized":
            return self._low + (np.clip(a, -1.0, 1.0) + 1.0) * self._scale
        return np.ascontiguousarray(a, dtype=np.float64)

    # -- helpers ---------------------------------------------------------------------------
    def normalize_action(self, absolute: np.ndarray) -> np.ndarray:
        """Map absolute actions to the normalized [-1, 1] space."""
        a = np.asarray(absolute, dtype=np.float64)
        return (2.0 * (a - self._low) / (self._high - self._low) - 1.0).astype(np.float32)
