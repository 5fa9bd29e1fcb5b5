"""The frames' patches as the tokenizer sees them: tiles of a code's size, and their distinct contents."""

from __future__ import annotations

import numpy as np


def tiles(frames: np.ndarray, patch: tuple[int, int]) -> np.ndarray:
    """uint8 frames (N, H, W) → their non-overlapping `patch`-sized tiles, row-major per frame: (N·h·w, ph·pw)."""
    ph, pw = patch
    n, H, W = frames.shape
    h, w = H // ph, W // pw
    cropped = frames[:, : h * ph, : w * pw].reshape(n, h, ph, w, pw)
    return np.ascontiguousarray(cropped.transpose(0, 1, 3, 2, 4).reshape(n * h * w, ph * pw))


def distinct_patches(frames: np.ndarray, patch: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """The distinct contents of the `patch`-sized tiles of `frames` (N, H, W), most frequent first:
    (contents uint8 (U, ph, pw), counts int64 (U,))."""
    flat = tiles(frames, patch)
    keys, counts = np.unique(flat.view(f"V{flat.shape[1]}").ravel(), return_counts=True)
    order = np.argsort(-counts, kind="stable")
    contents = keys[order].view(np.uint8).reshape(-1, *patch)
    return contents, counts[order]
