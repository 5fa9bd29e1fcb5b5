"""The world's colours, as the paper's figures show them: matplotlib's viridis over the uint8 pixel values.

Free space is violet, obstacles blue to cyan by class, the agent green and the goal yellow. Row 0 of the world is
the bottom, so images are flipped to put it there (`origin="lower"`). The environment renders itself with them
(`RoadEnv.render`); `dynplan.render` builds GIFs and error images on them.
"""

from __future__ import annotations

import functools

import numpy as np

from dynplan.env.config import AGENT_VALUE
from dynplan.env.road import round_px


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
