"""Saving rendered frames. Frames are (height, width, 3) uint8 arrays, row 0 at the top."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from equigym._optional import require


def save_gif(frames: Sequence[np.ndarray], path: str | Path, fps: float = 20.0) -> Path:
    """Write frames as an animated GIF (needs Pillow: ``pip install equigym[media]``)."""
    image = require("PIL.Image", "save_gif")
    if len(frames) == 0:
        raise ValueError("save_gif: no frames to write")
    images = [image.fromarray(np.asarray(f, dtype=np.uint8)) for f in frames]
    path = Path(path)
    images[0].save(path, save_all=True, append_images=images[1:], duration=int(1000 / fps), loop=0)
    return path
