"""The history a prior conditions on: the `context` frames before a target, with frame 0 repeated before an
episode's start.

One rule for training and prediction alike. The planner's first decision (frame 4) has seen 5 frames, so a prior
with a longer context than that asks for frames before the episode began; both the training windows and the world
model's contexts fill them with the first frame (the world as it stood before anything was observed to move), so
the model learns on exactly the histories it is later shown.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from dynplan.env.agent import FIRST_DECISION_FRAME


def context_indices(targets: np.ndarray | int, context: int) -> np.ndarray:
    """Frame indices (…, context) of the history of each target frame index: targets − context … targets − 1, the
    indices before 0 replaced by 0 (oldest first)."""
    if context < 1:
        raise ValueError(f"context must be ≥ 1, got {context}")
    targets = np.asarray(targets, dtype=np.int64)
    if (targets < 1).any():
        raise ValueError(f"a target needs at least one frame before it; got target index {int(targets.min())}")
    return np.maximum(targets[..., None] - context + np.arange(context), 0)


def last_frames(frames: Sequence[np.ndarray] | np.ndarray, context: int) -> list[np.ndarray]:
    """The last `context` of the observed `frames` (oldest first), the first frame repeated before them when fewer
    than `context` were observed."""
    if len(frames) == 0:
        raise ValueError("no frames observed: the history needs at least one")
    return [frames[int(i)] for i in context_indices(len(frames), context)]


def first_target(context: int) -> int:
    """The first frame index a prior with this context is trained to predict: `context` (no padding) when the
    planner never asks for more history than that, else the first frame it predicts, FIRST_DECISION_FRAME + 1."""
    return min(context, FIRST_DECISION_FRAME + 1)
