"""The files shipped inside the package: the Panda URDF and the trained diffusion policies.

Everything is found through :func:`asset_path`, relative to the installed ``equigym`` package
(``importlib.resources``), so a wheel installed anywhere finds them without a checkout. In a
checkout, ``python/equigym/shipped`` links to the repository's ``assets/`` directory.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

__all__ = ["ASSET_DIR_NAME", "asset_dir", "asset_path", "policy_path", "urdf_path"]

#: The package directory that holds the shipped files.
ASSET_DIR_NAME = "shipped"


def asset_dir(*parts: str) -> Path:
    """A directory of shipped files (it need not exist), e.g. ``asset_dir("edp")``."""
    return Path(str(resources.files("equigym").joinpath(ASSET_DIR_NAME, *parts)))


def asset_path(*parts: str) -> Path:
    """Path of a shipped file, e.g. ``asset_path("panda", "panda.urdf")``.

    Raises :class:`equigym.errors.MissingFileError` (a ``FileNotFoundError``) when it is absent.
    """
    from equigym.errors import MissingFileError

    path = asset_dir(*parts)
    if not path.is_file():
        raise MissingFileError(2, f"equigym ships no file {'/'.join(parts)}", str(path))
    return path


def urdf_path() -> Path:
    """The shipped Panda URDF (the robot every environment loads by default)."""
    return asset_path("panda", "panda.urdf")


def policy_path(task: str) -> Path:
    """The diffusion policy shipped for ``task`` (``lift``, ``stack``, ``square``)."""
    from equigym.errors import MissingFileError

    try:
        return asset_path("edp", f"{task}.safetensors")
    except MissingFileError as exc:
        raise MissingFileError(
            2,
            f"no shipped diffusion policy for '{task}'; train one with `python -m baselines.edp train` "
            "and pass policy=<file>",
            exc.filename,
        ) from None
