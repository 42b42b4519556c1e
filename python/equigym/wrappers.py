"""Gymnasium wrappers that expose the symmetry to agents."""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np

from equigym.symmetry import Field, Symmetry


class SymmetryWrapper(gymnasium.Wrapper):
    """Expose the task's group and field layouts to an agent, and act with the group.

    The wrapped env behaves exactly as before. Agents (equivariant networks, augmentation)
    read :attr:`symmetry`, :attr:`group`, :attr:`observation_layout` and
    :attr:`action_layout`; :meth:`rotate` turns the simulator's current state by g.

    Normalized actions (``action_mode="normalized"``) transform like absolute ones: x and y
    share one symmetric scale and z, rotations and width are invariant under the scaling.
    """

    def __init__(self, env: gymnasium.Env, *, group: str = "C8", chunk_len: int = 4) -> None:
        super().__init__(env)
        self.symmetry = Symmetry.for_env(env, group=group, chunk_len=chunk_len)

    @property
    def group(self) -> str:
        return self.symmetry.group

    @property
    def group_order(self) -> int | None:
        return self.symmetry.order

    @property
    def observation_layout(self) -> list[Field]:
        return self.symmetry.layout("observation")

    @property
    def action_layout(self) -> list[Field]:
        return self.symmetry.layout("action")

    def transform_observation(self, obs: np.ndarray, g: Any = None, *, angle: Any = None) -> np.ndarray:
        return self.symmetry.act_observation(obs, g, angle=angle)

    def transform_action(self, action: np.ndarray, g: Any = None, *, angle: Any = None) -> np.ndarray:
        return self.symmetry.act_action(action, g, angle=angle)

    def rotate(self, g: int | None = None, *, angle: float | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        """Rotate the current simulator state by g; returns the new observation and the arm's fit."""
        fit = self.symmetry.transform_state(self.env, g, angle=angle)
        obs = self.env.unwrapped.core.observe().astype(np.float32)
        return obs, fit


class TerminateOnSuccess(gymnasium.Wrapper):
    """End an episode at its first successful step (``terminated=True``).

    The latent environments run to the horizon, as DSRL's do, so a training return counts the
    time spent successful. After a lift that depends on behaviour the demonstrations never show
    (they end at success) and the base policy loses every cube it lifts (docs/steering.md,
    "Steerability"). Terminating on success makes the return count the steps to success, which
    is what the evaluation measures. Wrap training environments only; evaluate unwrapped.
    """

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        return obs, reward, bool(terminated or info.get("success", False)), truncated, info
