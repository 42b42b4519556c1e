"""A stable-baselines3 replay buffer that rotates every sampled transition by a random
element of C_N (symmetry data augmentation for off-policy agents).

>>> from equigym.replay import SymmetricReplayBuffer
>>> SAC("MlpPolicy", env, replay_buffer_class=SymmetricReplayBuffer,
...     replay_buffer_kwargs={"task": "lift"})

SB3 stores Box actions scaled to [-1, 1]. The scaling commutes with the group for equigym's
action spaces (x and y share one symmetric range; z, rotations and width are invariant or
unscaled), so rotating stored actions equals rotating raw ones.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from equigym._optional import require

torch = require("torch", "equigym.replay")
require("stable_baselines3", "equigym.replay")

from stable_baselines3.common.buffers import ReplayBuffer  # noqa: E402
from stable_baselines3.common.type_aliases import ReplayBufferSamples  # noqa: E402

from equigym.symmetry import Symmetry  # noqa: E402


class SymmetricReplayBuffer(ReplayBuffer):
    """:class:`ReplayBuffer` whose samples are rotated by random group elements.

    Extra args: ``task`` (or ``symmetry``), ``group`` (default ``"C8"``), ``action_space``
    (``"action"`` for raw envs, ``"latent"`` for latent-noise envs), ``seed``.
    """

    def __init__(
        self,
        *args: Any,
        task: str | None = None,
        symmetry: Symmetry | None = None,
        group: str = "C8",
        action_space: str = "action",
        chunk_len: int = 4,
        seed: int | None = None,
        **kwargs: Any,
    ) -> None:
        super().__init__(*args, **kwargs)
        if symmetry is None:
            if task is None:
                raise ValueError("SymmetricReplayBuffer needs task= or symmetry=")
            symmetry = Symmetry(task, group=group, chunk_len=chunk_len)
        if symmetry.order is None:
            raise ValueError("SymmetricReplayBuffer samples elements of C_N; use group='C<N>'")
        self.symmetry = symmetry
        self.action_space_name = action_space
        self._rng = np.random.default_rng(seed)

    def _get_samples(self, batch_inds: np.ndarray, env: Any = None) -> ReplayBufferSamples:
        s = super()._get_samples(batch_inds, env)
        g = self._rng.integers(0, self.symmetry.order, size=len(batch_inds))

        def rot(t: torch.Tensor, space: str) -> torch.Tensor:
            x = t.detach().cpu().numpy()
            return torch.as_tensor(self.symmetry.act(space, x, g=g), device=t.device, dtype=t.dtype)

        return s._replace(
            observations=rot(s.observations, "observation"),
            actions=rot(s.actions, self.action_space_name),
            next_observations=rot(s.next_observations, "observation"),
        )
