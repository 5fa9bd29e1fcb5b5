"""Pictures built from the world's colours (`dynplan.env.colors`): enlarged frames, prediction-error images, side
by side columns and GIFs."""

from __future__ import annotations

import io
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from dynplan.env.colors import colorize, palette
from dynplan.env.config import GOAL_VALUE
from dynplan.files import write_bytes_atomic
from dynplan.world import DEFAULT_WORLD, world


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


FALSE_NEGATIVE = np.array([230, 30, 30], np.uint8)  # obstacle predicted as free: red
FALSE_POSITIVE = np.array([40, 90, 255], np.uint8)  # free predicted as obstacle: blue
PREDICTED_GOAL = np.array([255, 150, 0], np.uint8)  # orange, drawn over the true goal (yellow)


def error_image(true: np.ndarray, predicted: np.ndarray, world_name: str = DEFAULT_WORLD) -> np.ndarray:
    """The paper's Figure 1 error panel for one frame pair (H, W) of the world `world_name` → RGB (H, W, 3), row 0
    at the bottom: false negatives red, false positives blue, true goal yellow, predicted goal orange (orange alone
    = exact); obstacles are the values that are not the world's clear ground."""
    colours, clear = palette(), world(world_name).clear
    true_obstacle, predicted_obstacle = ~np.isin(true, clear), ~np.isin(predicted, clear)
    image = np.broadcast_to(colours[world(world_name).background], (*true.shape, 3)).copy()
    image[true_obstacle & predicted_obstacle] = colours[true[true_obstacle & predicted_obstacle]]
    image[true_obstacle & ~predicted_obstacle] = FALSE_NEGATIVE
    image[~true_obstacle & predicted_obstacle] = FALSE_POSITIVE
    image[true == GOAL_VALUE] = colours[GOAL_VALUE]
    image[predicted == GOAL_VALUE] = PREDICTED_GOAL
    return np.flip(image, axis=0)


def side_by_side(images: Sequence[np.ndarray], gap: int = 1) -> np.ndarray:
    """Concatenate RGB images (H, W, 3) left to right with a white `gap`-pixel column between them."""
    H = images[0].shape[0]
    spacer = np.full((H, gap, 3), 255, np.uint8)
    parts: list[np.ndarray] = []
    for i, image in enumerate(images):
        parts += [spacer, image] if i else [image]
    return np.concatenate(parts, axis=1)


def comparison_columns(true: np.ndarray, predicted: np.ndarray) -> np.ndarray:
    """RGB columns, one per frame pair of `true` and `predicted` (n, H, W): the true frame over the predicted one
    over their error panel (`error_image`), white lines between them."""
    columns = []
    for t, p in zip(true, predicted, strict=True):
        parts = [colorize(t), colorize(p), error_image(t, p)]
        spacer = np.full((1, t.shape[1], 3), 255, np.uint8)
        columns.append(np.concatenate([parts[0], spacer, parts[1], spacer, parts[2]]))
    return side_by_side(columns)
