"""Pictures of the world: the paper's colours (viridis over pixel values) and GIFs.

Free space is violet, obstacles blue to cyan by class, the agent green and the goal yellow — matplotlib's
viridis applied to the uint8 values, as in the paper's figures. Row 0 of the world is the bottom, so images
are flipped to put it there (`origin="lower"`).
"""

from __future__ import annotations

import functools
import io
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from dynplan.env.config import AGENT_VALUE
from dynplan.env.road import round_px
from dynplan.files import write_bytes_atomic


@functools.cache
def palette() -> np.ndarray:
    """(256, 3) uint8 lookup table: pixel value → RGB (viridis)."""
    import matplotlib

    rgba = matplotlib.colormaps["viridis"](np.linspace(0.0, 1.0, 256))
    return np.round(rgba[:, :3] * 255).astype(np.uint8)


def draw_agent(frames: np.ndarray, agent: np.ndarray) -> np.ndarray:
    """Copy of `frames` (..., H, W) with the agent at `agent` (..., 2) drawn as value 200 where on the grid."""
    out = np.array(frames, copy=True)
    H, W = out.shape[-2:]
    px = round_px(agent).reshape(-1, 2)
    flat = out.reshape(-1, H, W)
    on_grid = (px[:, 0] >= 0) & (px[:, 0] < H) & (px[:, 1] >= 0) & (px[:, 1] < W)
    idx = np.nonzero(on_grid)[0]
    flat[idx, px[idx, 0], px[idx, 1]] = AGENT_VALUE
    return out


def colorize(frames: np.ndarray, agent: np.ndarray | None = None) -> np.ndarray:
    """World frames (..., H, W) uint8 → RGB images (..., H, W, 3) with row 0 at the bottom."""
    if agent is not None:
        frames = draw_agent(frames, agent)
    return np.flip(palette()[frames], axis=-3)


def upscale(images: np.ndarray, scale: int) -> np.ndarray:
    """Nearest-neighbour enlargement of (..., H, W, 3) images by an integer factor."""
    return images.repeat(scale, axis=-3).repeat(scale, axis=-2)


def write_gif(
    path: str | os.PathLike, images: Sequence[np.ndarray] | np.ndarray, fps: float = 10.0, scale: int = 6
) -> Path:
    """Write RGB images (T, H, W, 3) as a looping GIF, enlarged `scale` times, atomically."""
    from PIL import Image

    images = upscale(np.asarray(images), scale)
    if images.ndim != 4 or images.shape[-1] != 3 or len(images) == 0:
        raise ValueError(f"write_gif needs RGB images shaped (T, H, W, 3), got {images.shape}")
    pictures = [Image.fromarray(im) for im in images]
    buffer = io.BytesIO()
    pictures[0].save(buffer, format="GIF", save_all=True, append_images=pictures[1:], duration=int(1000 / fps), loop=0)
    return write_bytes_atomic(path, buffer.getvalue())
