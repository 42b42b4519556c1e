"""escnn field types for equigym's flat vectors, shared by the EDP and the steering agents."""

from __future__ import annotations

from typing import Any


def block_types(gspace: Any, blocks: list[tuple[int, list[int]]]) -> tuple[list[Any], list[int]]:
    """The escnn representation of each irreducible block of a space (``Symmetry.blocks``:
    frequency 0 -> trivial, 1 -> irrep(1)) and the permutation that takes a vector from the
    task's natural field order to block order (each rho1 pair contiguous, as escnn needs)."""
    rep = {0: gspace.trivial_repr, 1: gspace.irrep(1)}
    return [rep[f] for f, _ in blocks], [i for _, idx in blocks for i in idx]
