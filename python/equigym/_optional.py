"""Optional dependencies: one place that imports them and says which extra installs them."""

from __future__ import annotations

import importlib
from types import ModuleType

#: Optional module -> the ``equigym`` extra that installs it.
EXTRAS: dict[str, str] = {
    "PIL": "media",
    "matplotlib": "plot",
    "h5py": "train",
    "torch": "train",
    "safetensors": "train",
    "stable_baselines3": "train",
    "escnn": "train",
    "ray": "sweep",
}


def require(module: str, purpose: str) -> ModuleType:
    """Import ``module`` or raise ImportError naming the extra to install for ``purpose``."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        top = module.split(".")[0]
        extra = EXTRAS.get(top)
        hint = f"pip install 'equigym[{extra}]'" if extra else f"pip install {top}"
        raise ImportError(f"{purpose} needs {top}, which is not installed: {hint}") from exc
