"""Saving rendered frames. Frames are (height, width, 3) uint8 arrays, row 0 at the top."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np


def save_gif(frames: Sequence[np.ndarray], path: str | Path, fps: float = 20.0) -> Path:
    """Write frames as an animated GIF (needs Pillow: ``pip install equigym[media]``)."""
    try:
        from PIL import Image
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise ImportError("save_gif needs Pillow: pip install 'equigym[media]'") from e
    if len(frames) == 0:
        raise ValueError("save_gif: no frames to write")
    images = [Image.fromarray(np.asarray(f, dtype=np.uint8)) for f in frames]
    path = Path(path)
    images[0].save(path, save_all=True, append_images=images[1:], duration=int(1000 / fps), loop=0)
    return path
