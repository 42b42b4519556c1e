"""Every exception equigym raises, under one base class, :class:`EquigymError`.

The Rust core raises these same classes (mapped in one place, ``bindings/src/errors.rs``).
Each also subclasses the builtin exception a caller would expect (``ValueError`` for bad
input, ``RuntimeError`` for calls out of order, ``FileNotFoundError`` for missing files), so
``except ValueError`` keeps working. They live in this importable module, so they pickle.
"""

from __future__ import annotations

__all__ = [
    "EquigymError",
    "EquigymIOError",
    "InvalidInputError",
    "InvalidStateError",
    "MissingFileError",
    "PhysicsError",
    "PolicyError",
    "ResetNeeded",
    "UrdfError",
]


class EquigymError(Exception):
    """Base class of every equigym exception."""


class InvalidInputError(EquigymError, ValueError):
    """An argument, option, array shape or value (NaN, infinity) that equigym cannot use."""


class UrdfError(EquigymError, ValueError):
    """The robot description (URDF) cannot be used."""


class InvalidStateError(EquigymError, ValueError):
    """A saved state cannot be restored (wrong task, corrupt or truncated bytes)."""


class PolicyError(EquigymError, ValueError):
    """A diffusion-policy file is corrupt, truncated or does not fit the task."""


class PhysicsError(EquigymError, RuntimeError):
    """The physics engine failed inside a step (only reachable from hand-made state bytes);
    the episode has ended and ``reset()`` starts a new one."""


class ResetNeeded(EquigymError, RuntimeError):
    """The environment must be reset before this call."""


class MissingFileError(EquigymError, FileNotFoundError):
    """A file named by an option (URDF, policy) does not exist."""


class EquigymIOError(EquigymError, OSError):
    """Reading or writing a file failed for another reason than its absence."""
