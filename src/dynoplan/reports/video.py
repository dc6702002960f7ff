"""MP4 videos of rendered episodes (imageio with the ffmpeg its wheel ships)."""

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import numpy.typing as npt

from dynoplan.io import write_with


def write_mp4(path: Path, frames: Sequence[npt.NDArray[np.uint8]], fps: int) -> Path:
    """Write ``frames`` (H, W, 3) ``uint8`` as an H.264 MP4 at ``fps``, atomically."""
    import imageio.v2 as imageio

    if not frames:
        raise ValueError("no frames to write")
    write_with(path, lambda p: imageio.mimwrite(p, list(frames), fps=fps,
                                                codec="libx264", quality=7))
    return path


__all__ = ["write_mp4"]
