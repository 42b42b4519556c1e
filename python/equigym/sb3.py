"""Stable-Baselines3 adapter: an equigym vector environment as an SB3 ``VecEnv``.

>>> from stable_baselines3 import SAC
>>> from equigym.sb3 import EquiVecEnv
>>> venv = EquiVecEnv("EquiLift-v0", num_envs=4, action_mode="normalized", reward="dense")
>>> SAC("MlpPolicy", venv).learn(10_000)
>>> latent = EquiVecEnv("EquiLift-Latent-v0", num_envs=4)   # DSRL's latent-noise MDP, batched DDIM

All B environments step in one Rust call (see :mod:`equigym.vector`). SB3 expects an episode
that ends to be reset within the same step, so the adapter runs the Rust batch with
``same_step`` auto-reset and, for every sub-environment whose episode ended:

- ``infos[i]["terminal_observation"]`` is the last observation of the ended episode
  (the returned observation is already the next episode's first one);
- ``infos[i]["TimeLimit.truncated"]`` is True when the episode was cut at the horizon and
  did not terminate, so off-policy agents bootstrap through time-limit ends (terminated and
  truncated stay apart);
- ``infos[i]["is_success"]`` carries the task's success flag (every step), which SB3 logs.

Stable-Baselines3 is optional for equigym; this module needs it installed
(``pip install 'equigym[train]'``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from equigym._optional import require
from equigym.vector import NativeVectorEnv

try:
    from stable_baselines3.common.vec_env import VecEnv as _SB3VecEnv
except ImportError as _error:  # pragma: no cover - exercised only without SB3
    _SB3VecEnv = None
    _SB3_IMPORT_ERROR: ImportError | None = _error
else:
    _SB3_IMPORT_ERROR = None

__all__ = ["EquiVecEnv"]


def _vector_env(env_id_or_env: Any, num_envs: int, kwargs: dict[str, Any]) -> NativeVectorEnv:
    if isinstance(env_id_or_env, NativeVectorEnv):
        if kwargs:
            raise ValueError("keyword arguments are only used when building the vector env from an id")
        if env_id_or_env.autoreset_mode != "same_step":
            raise ValueError(
                "EquiVecEnv needs a vector env made with autoreset_mode='same_step' "
                "(SB3 resets finished episodes within the step); or pass the env id instead"
            )
        return env_id_or_env
    import gymnasium

    kwargs = dict(kwargs)
    kwargs["autoreset_mode"] = "same_step"
    env = gymnasium.make_vec(env_id_or_env, num_envs=num_envs, vectorization_mode="vector_entry_point", **kwargs)
    if not isinstance(env.unwrapped, NativeVectorEnv):
        raise ValueError(f"{env_id_or_env!r} is not an equigym environment id")
    return env.unwrapped


if _SB3VecEnv is None:

    class EquiVecEnv:  # type: ignore[no-redef]
        """Placeholder: Stable-Baselines3 is not installed."""

        def __init__(self, *args: Any, **kwargs: Any) -> None:
            require("stable_baselines3", "equigym.sb3.EquiVecEnv")

else:

    class EquiVecEnv(_SB3VecEnv):  # type: ignore[no-redef]
        """An equigym vector env as a Stable-Baselines3 ``VecEnv``.

        Args:
            env: a gymnasium id (``"EquiLift-v0"``, ``"EquiLift-Latent-v0"``, ...) or an equigym
                vector env made with ``autoreset_mode="same_step"``.
            num_envs: number of sub-environments (with an id).
            **kwargs: options of the environment (``reward``, ``action_mode``, ``threads``, ``horizon``, ...).
        """

        def __init__(self, env: Any, num_envs: int = 1, **kwargs: Any) -> None:
            self.venv = _vector_env(env, num_envs, kwargs)
            self.render_mode = None
            super().__init__(self.venv.num_envs, self.venv.single_observation_space, self.venv.single_action_space)
            self._actions: np.ndarray | None = None

        # -- VecEnv API ----------------------------------------------------------------------
        def reset(self) -> np.ndarray:
            if all(s is not None for s in self._seeds):
                seeds: Any = list(self._seeds)
            elif any(s is not None for s in self._seeds):
                # Unseeded sub-environments draw from the vector env's generator.
                draws = self.venv.np_random.integers(0, 2**63 - 1, size=self.num_envs, dtype=np.int64)
                seeds = [int(s) if s is not None else int(d) for s, d in zip(self._seeds, draws)]
            else:
                seeds = None
            obs, info = self.venv.reset(seed=seeds)
            self.reset_infos = [{"episode_seed": int(s)} for s in info["episode_seed"]]
            self._reset_seeds()
            self._reset_options()
            return obs

        def step_async(self, actions: np.ndarray) -> None:
            self._actions = actions

        def step_wait(self):
            obs, rewards, terminated, truncated, info = self.venv.step(self._actions)
            dones = terminated | truncated
            success = info["success"]
            infos: list[dict[str, Any]] = [{"is_success": bool(s)} for s in success]
            if "executed" in info:  # latent-action envs: primitive steps run by each latent step
                for i, n in enumerate(info["executed"]):
                    infos[i]["executed"] = int(n)
            if dones.any():
                final = info["final_obs"]
                for i in np.flatnonzero(dones):
                    infos[i]["terminal_observation"] = final[i]
                    infos[i]["TimeLimit.truncated"] = bool(truncated[i] and not terminated[i])
                    infos[i]["episode_seed"] = int(info["episode_seed"][i])
            return obs, rewards.astype(np.float32), dones, infos

        def close(self) -> None:
            self.venv.close()

        def seed(self, seed: int | None = None) -> Sequence[int | None]:
            if seed is None:
                seed = int(np.random.randint(0, 2**31 - 1))
            self._seeds = [seed + i for i in range(self.num_envs)]
            return self._seeds

        # -- attribute access: every sub-environment shares the vector env's attributes -------
        def _indices(self, indices: Any) -> list[int]:
            return list(self._get_indices(indices))

        def get_attr(self, attr_name: str, indices: Any = None) -> list[Any]:
            value = getattr(self, attr_name) if attr_name == "render_mode" else getattr(self.venv, attr_name)
            return [value for _ in self._indices(indices)]

        def set_attr(self, attr_name: str, value: Any, indices: Any = None) -> None:
            if self._indices(indices) != list(range(self.num_envs)):
                raise ValueError("equigym sub-environments share their attributes; set them for all indices")
            setattr(self.venv, attr_name, value)

        def env_method(
            self, method_name: str, *method_args: Any, indices: Any = None, **method_kwargs: Any
        ) -> list[Any]:
            result = getattr(self.venv, method_name)(*method_args, **method_kwargs)
            return [result for _ in self._indices(indices)]

        def env_is_wrapped(self, wrapper_class: type, indices: Any = None) -> list[bool]:
            return [False for _ in self._indices(indices)]

        def get_images(self) -> Sequence[np.ndarray | None]:
            return [None for _ in range(self.num_envs)]
