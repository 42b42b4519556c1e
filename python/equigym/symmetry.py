"""The symmetry layer: the planar rotation group acting on observations, actions, action
chunks, latent noise and simulator states, and the measurement of symmetry breaking.

The group rotates the scene about the world z axis through the table centre. C_N elements are
given by index ``g`` (rotation by ``2 pi g / N``, counter-clockwise seen from above); any SO(2)
rotation by ``angle`` (radians). Arrays may carry any leading batch axes; ``g`` or ``angle``
may be one value or one per row.

>>> sym = Symmetry("lift")                        # C8, chunks of 4 actions
>>> rotated = sym.act_observation(obs, g=1)       # 45 degrees
>>> rotated = sym.act_action(actions, g=np.arange(len(actions)) % 8)
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from equigym import _core


@dataclass(frozen=True)
class Field:
    """One named slice of a flat vector, with its representation (``rho1 + rho0``, ...)."""

    name: str
    start: int
    len: int
    kind: str
    rep: str

    @property
    def slice(self) -> slice:
        return slice(self.start, self.start + self.len)


class Symmetry:
    """A task's group action.

    Args:
        task: task id (``"lift"``, ``"stack"``, ``"square"``).
        group: ``"C<N>"`` (default ``"C8"``) or ``"SO2"`` (elements by angle only).
        chunk_len: actions per action chunk; the latent noise has the chunk's layout.
        variant: the task variant (layouts do not depend on it today).
    """

    def __init__(self, task: str, *, group: str = "C8", chunk_len: int = 4, variant: str | None = None) -> None:
        self._core = _core.TaskSymmetry(task, group=group, chunk_len=chunk_len, variant=variant)

    @classmethod
    def for_env(cls, env: Any, *, group: str = "C8", chunk_len: int = 4) -> Symmetry:
        """The symmetry of a (possibly wrapped) equigym environment."""
        return cls(_core_env(env).task, group=group, chunk_len=chunk_len)

    # -- the group ------------------------------------------------------------------------
    @property
    def task(self) -> str:
        return self._core.task

    @property
    def group(self) -> str:
        return self._core.group

    @property
    def order(self) -> int | None:
        """N for C_N; None for SO(2)."""
        return self._core.group_order

    @property
    def chunk_len(self) -> int:
        return self._core.chunk_len

    @property
    def elements(self) -> list[int]:
        """Element indices of C_N (0 is the identity)."""
        if self.order is None:
            raise ValueError("SO(2) has no finite list of elements; use angle=")
        return list(range(self.order))

    def angle(self, g: int) -> float:
        """Rotation angle (radians) of element ``g``."""
        return self._core.element_angle(int(g))

    def dim(self, space: str) -> int:
        return self._core.dim(space)

    def layout(self, space: str) -> list[Field]:
        """The fields of ``space`` (``observation``, ``action``, ``chunk``, ``latent``)."""
        return [Field(**f) for f in self._core.layout(space)]

    def blocks(self, space: str) -> list[tuple[int, list[int]]]:
        """Irreducible blocks of ``space`` in order: ``(0, [i])`` for rho0, ``(1, [x, y])`` for rho1."""
        return self._core.blocks(space)

    def matrix(self, space: str, g: int | None = None, *, angle: float | None = None) -> npt.NDArray[np.float64]:
        """The (orthogonal) representation matrix of one element on ``space``."""
        return self._core.matrix(space, element=None if g is None else int(g), angle=angle)

    # -- acting on data -------------------------------------------------------------------
    def act(self, space: str, x: npt.ArrayLike, g: Any = None, *, angle: Any = None) -> np.ndarray:
        """g . x for an array whose last axis is ``space``'s dimension. Float32 stays float32."""
        arr = np.asarray(x)
        if arr.dtype.kind not in "fiu":
            raise TypeError(f"{space}: expected a numeric array, got dtype {arr.dtype}")
        data = np.ascontiguousarray(arr, dtype=np.float64)
        if (g is None) == (angle is None):
            raise ValueError("give exactly one of g (element index) or angle (radians)")
        if g is not None:
            idx = np.asarray(g)
            if idx.dtype.kind not in "iu":
                raise TypeError(f"g must be an integer element index (or array of them), got {idx.dtype}")
            out = self._core.act_elements(space, data, np.ascontiguousarray(idx.reshape(-1), dtype=np.int64))
        else:
            ang = np.ascontiguousarray(np.asarray(angle, dtype=np.float64).reshape(-1))
            out = self._core.act_angles(space, data, ang)
        return out.astype(arr.dtype, copy=False) if arr.dtype.kind == "f" else out

    def act_observation(self, obs: npt.ArrayLike, g: Any = None, *, angle: Any = None) -> np.ndarray:
        return self.act("observation", obs, g, angle=angle)

    def act_action(self, action: npt.ArrayLike, g: Any = None, *, angle: Any = None) -> np.ndarray:
        return self.act("action", action, g, angle=angle)

    def act_chunk(self, chunk: npt.ArrayLike, g: Any = None, *, angle: Any = None) -> np.ndarray:
        """A chunk is ``(..., chunk_len * 10)`` or ``(..., chunk_len, 10)``."""
        c = np.asarray(chunk)
        if c.ndim >= 2 and c.shape[-2:] == (self.chunk_len, 10):
            flat = c.reshape(*c.shape[:-2], self.chunk_len * 10)
            return self.act("chunk", flat, g, angle=angle).reshape(c.shape)
        return self.act("chunk", c, g, angle=angle)

    def act_latent(self, w: npt.ArrayLike, g: Any = None, *, angle: Any = None) -> np.ndarray:
        return self.act_chunk(w, g, angle=angle)

    # -- acting on the simulator ----------------------------------------------------------
    def transform_state(self, env: Any, g: int | None = None, *, angle: float | None = None) -> dict[str, Any]:
        """g . s: rotate the environment's current state in place (objects, hand and fingers
        with their velocities; the robot base stays, the arm is re-solved). Returns the arm's
        fit: ``position_error`` / ``rotation_error`` of the rotated hand and ``reachable``."""
        return self._core.transform_state(_core_env(env), element=None if g is None else int(g), angle=angle)


def _core_env(env: Any) -> _core.Env:
    """The Rust env behind a gymnasium env, wrapped or not."""
    inner = getattr(env, "unwrapped", env)
    core = getattr(inner, "core", inner)
    if not isinstance(core, _core.Env):
        raise TypeError(f"expected an equigym environment, got {type(env).__name__}")
    return core


def measure_breaking(
    task: str,
    *,
    group_order: int = 8,
    episodes: int = 20,
    states_per_episode: int = 4,
    probe_steps: int = 1,
    replay_slack: int = 30,
    seed: int = 0,
    **env_options: Any,
) -> dict[str, Any]:
    """Measure how much a task breaks the rotational symmetry.

    Runs the scripted expert for ``episodes`` seeds, then (a) compares step(g s, g a) with
    g step(s, a) on ``states_per_episode`` sampled states per episode for every element of
    C_N (observation, object and hand position errors, dense-reward and success mismatch,
    fraction of rotated states the arm cannot reach), and (b) replays each successful
    demonstration open loop after rotating its initial state and actions by each g.
    ``env_options`` are the environments' keyword arguments (``variant``, ``joint_limits``,
    ``controller``, ...); ``controller="cartesian"`` with ``joint_limits=False`` is the only
    setting whose physics commutes with the group up to the contact solver. The report's
    ``config`` names the variant, ``joint_limits`` and ``cartesian_control`` resolved.
    Returns a dict with ``config``, ``expert_successes``, ``invariance`` and ``replay`` rows.
    """
    text = _core.measure_symmetry_breaking(
        task,
        env=env_options,
        group_order=group_order,
        episodes=episodes,
        states_per_episode=states_per_episode,
        probe_steps=probe_steps,
        replay_slack=replay_slack,
        seed=seed,
    )
    return json.loads(text)


def summarize(report: dict[str, Any]) -> dict[str, float]:
    """Means over the non-identity elements (the identity row is the measurement floor)."""
    inv = [r for r in report["invariance"] if r["element"] != 0]
    rep = [r for r in report["replay"] if r["element"] != 0]

    def mean(rows: list[dict[str, Any]], key: str) -> float:
        return float(np.mean([r[key] for r in rows])) if rows else float("nan")

    demos = sum(r["demos"] for r in rep)
    floor = report["invariance"][0]
    return {
        "observation_error": mean(inv, "observation_error_mean"),
        "object_error_mm": 1e3 * mean(inv, "object_error_mean"),
        "hand_error_mm": 1e3 * mean(inv, "hand_error_mean"),
        "reward_error": mean(inv, "reward_error_mean"),
        "success_mismatch": mean(inv, "success_mismatch"),
        "unreachable": mean(inv, "unreachable"),
        "rotated_replay_success": (sum(r["successes"] for r in rep) / demos) if demos else float("nan"),
        "floor_observation_error": floor["observation_error_mean"],
    }
