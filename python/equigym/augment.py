"""Data augmentation with the group: demonstrations and replay-buffer batches.

Rewards, terminations and invariant fields do not change under the group; observations,
actions, action chunks and latent noise transform by their layouts' representations.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from equigym.symmetry import Symmetry


def augment_demonstration(
    symmetry: Symmetry,
    observations: np.ndarray,
    actions: np.ndarray,
    elements: Iterable[int] | None = None,
    *,
    action_space: str = "action",
) -> tuple[np.ndarray, np.ndarray]:
    """Every rotated copy of one demonstration.

    Returns ``(observations, actions)`` with a new leading axis of one copy per element
    (default: all of C_N, the identity first).
    """
    elems = list(symmetry.elements if elements is None else elements)
    obs = np.stack([symmetry.act("observation", observations, g=g) for g in elems])
    act = np.stack([symmetry.act(action_space, actions, g=g) for g in elems])
    return obs, act


def rotate_batch(
    symmetry: Symmetry,
    batch: Mapping[str, np.ndarray],
    spaces: Mapping[str, str],
    rng: np.random.Generator,
) -> dict[str, np.ndarray]:
    """Rotate each sample of a batch by its own random element of C_N.

    ``spaces`` maps batch keys to spaces, e.g. ``{"obs": "observation", "next_obs":
    "observation", "actions": "action"}``; other keys pass through. A sample's observation,
    next observation and action turn by the same element, so transitions stay consistent.
    """
    if symmetry.order is None:
        raise ValueError("rotate_batch samples elements of C_N; build the Symmetry with group='C<N>'")
    keys = [k for k in spaces if k in batch]
    if not keys:
        raise ValueError(f"none of {list(spaces)} is in the batch (keys: {list(batch)})")
    n = len(batch[keys[0]])
    g = rng.integers(0, symmetry.order, size=n)
    out: dict[str, Any] = dict(batch)
    for key in keys:
        out[key] = symmetry.act(spaces[key], batch[key], g=g)
    return out
