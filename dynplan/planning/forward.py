"""The forward-model seam: what the planner asks of a world model.

Given the frames observed so far (frames 0 … t), a forward model predicts the next k frames t+1 … t+k. The
world does not depend on the agent, so one prediction serves every rollout of a decision. Implementations:
`OracleModel` (the true future of a recorded world — the upper bound), `ZeroModel` (empty road, goal unknown —
a sanity floor); the learned VQ-VAE + PixelCNN model plugs in behind the same `predict`. A model that can predict
for many episodes at once also has a hashable `batch_key` (models with equal keys batch together), a static
`predict_batch(models, observed, ks)`, which `run_episodes` calls once per step for each group, and `cost(k)`, the
relative work of a k-frame prediction, by which the group's time is shared.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from dynplan.env.config import GOAL_VALUE
from dynplan.env.road import World


@dataclass(frozen=True)
class Prediction:
    """Predicted frames t+1 … t+k.

    frames: (k, H, W) uint8 world frames (free 0, obstacles, goal 244)
    goal:   (k, 2) float64 predicted goal centre (y, x) per frame; NaN where the goal is not visible
    """

    frames: np.ndarray
    goal: np.ndarray

    @classmethod
    def from_frames(cls, frames: np.ndarray) -> Prediction:
        return cls(frames, goal_centres(frames))


class ForwardModel(Protocol):
    """Predicts the future of the world from what has been observed."""

    name: str

    def predict(self, observed: np.ndarray, k: int) -> Prediction:
        """`observed`: (t+1, H, W) uint8 frames 0 … t; returns the prediction of frames t+1 … t+k."""
        ...


def goal_centres(frames: np.ndarray) -> np.ndarray:
    """(k, 2) mean (row, col) of each frame's visible goal pixels — the block's centre, (r + 0.5, c + 0.5), when
    fully visible — in the agent's coordinates; NaN where no goal pixel is visible."""
    k = len(frames)
    t, y, x = np.nonzero(frames == GOAL_VALUE)
    count = np.bincount(t, minlength=k).astype(np.float64)
    centre = np.full((k, 2), np.nan)
    seen = count > 0
    centre[seen, 0] = np.bincount(t, weights=y, minlength=k)[seen] / count[seen]
    centre[seen, 1] = np.bincount(t, weights=x, minlength=k)[seen] / count[seen]
    return centre


class OracleModel:
    """The true future: frames t+1 … t+k of the recorded world (fewer near the episode's end)."""

    name = "oracle"

    def __init__(self, world: World):
        self.frames = world.frames

    def predict(self, observed: np.ndarray, k: int) -> Prediction:
        t = len(observed) - 1
        return Prediction.from_frames(self.frames[t + 1 : t + 1 + k])


class ZeroModel:
    """Predicts an empty road and no goal: the planner sees neither obstacles nor where to go."""

    name = "zero"

    def predict(self, observed: np.ndarray, k: int) -> Prediction:
        H, W = observed.shape[1:]
        return Prediction(np.zeros((k, H, W), np.uint8), np.full((k, 2), np.nan))
