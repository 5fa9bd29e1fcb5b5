"""The forward-model seam: what the planner asks of a world model, declared as one batched call.

Given the frames observed so far (frames 0 … t), a forward model predicts the next k frames t+1 … t+k. The
world does not depend on the agent, so one prediction serves every rollout of a decision. `run_episodes` plays
many episodes in lockstep and, at each step, groups the live episodes' models by `(type(model), model.batch_key)`
and asks each group once: `predict_batch(models, observed, ks)`. `predict(observed, k)` is its batch of one.
`cost(k)` is the relative work of a k-frame prediction, by which a group's time is shared between its episodes.

Implementations: `OracleModel` (the true future of a recorded world — the upper bound), `ZeroModel` (empty road,
goal unknown — a floor) and the learned VQ-VAE + PixelCNN model (`dynplan.models.world_model`). A new model
subclasses `ForwardModel` and writes `predict`; it batches with others only if it overrides `batch_key` and
`predict_batch` (the defaults predict one model at a time).
"""

from __future__ import annotations

import time
from collections.abc import Hashable, Sequence
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

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


@runtime_checkable
class ForwardModel(Protocol):
    """Predicts the future of the world from what has been observed, for one episode or many at once.

    Shapes: observed (t+1, H, W) uint8 frames 0 … t of one episode; a prediction holds (k, H, W) frames.
    """

    name: str

    def predict(self, observed: np.ndarray, k: int) -> Prediction:
        """`observed`: (t+1, H, W) uint8 frames 0 … t; returns the prediction of frames t+1 … t+k."""
        ...

    @property
    def batch_key(self) -> Hashable:
        """Models of one type with equal keys predict together in one `predict_batch` call (e.g. the same
        weights on the same device); by default each model is a group of its own."""
        return id(self)

    def cost(self, k: int) -> float:
        """The relative work of a k-frame prediction: how a group's time is shared between its episodes."""
        return float(k)

    @classmethod
    def predict_batch(
        cls, models: Sequence[ForwardModel], observed: Sequence[np.ndarray], ks: Sequence[int]
    ) -> list[Prediction]:
        """Each model's prediction of its own episode: `observed[e]` (t_e+1, H, W) uint8, `ks[e]` frames ahead.
        `models` share one `batch_key` and this type. By default one `predict` after another."""
        return [model.predict(o, k) for model, o, k in zip(models, observed, ks, strict=True)]


def predict_together(
    models: Sequence[ForwardModel], observed: Sequence[np.ndarray], ks: Sequence[int]
) -> tuple[list[Prediction], list[float]]:
    """Each model's prediction of its own episode (`observed[e]`, `ks[e]` frames ahead) and the ms each took: one
    `predict_batch` per group of models of one type and `batch_key`, whose time is shared in proportion to what each
    asked for (`cost`). How every world's lockstep runner asks its episodes' models at a step."""
    out: list[Prediction | None] = [None] * len(models)
    ms = [0.0] * len(models)
    groups: dict[tuple[type, object], list[int]] = {}
    for i, model in enumerate(models):
        groups.setdefault((type(model), model.batch_key), []).append(i)
    for (kind, _), members in groups.items():
        start = time.perf_counter()
        predictions = kind.predict_batch(
            [models[i] for i in members], [observed[i] for i in members], [ks[i] for i in members]
        )
        spent = (time.perf_counter() - start) * 1e3
        costs = [models[i].cost(ks[i]) for i in members]
        for i, prediction, cost in zip(members, predictions, costs, strict=True):
            out[i], ms[i] = prediction, spent * cost / sum(costs)
    return out, ms  # type: ignore[return-value]


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


class OracleModel(ForwardModel):
    """The true future: frames t+1 … t+k of the recorded world (fewer near the episode's end)."""

    name = "oracle"

    def __init__(self, world: World):
        self.frames = world.frames

    def predict(self, observed: np.ndarray, k: int) -> Prediction:
        t = len(observed) - 1
        return Prediction.from_frames(self.frames[t + 1 : t + 1 + k])


class ZeroModel(ForwardModel):
    """Predicts an empty road and no goal: the planner sees neither obstacles nor where to go."""

    name = "zero"

    def predict(self, observed: np.ndarray, k: int) -> Prediction:
        H, W = observed.shape[1:]
        return Prediction(np.zeros((k, H, W), np.uint8), np.full((k, 2), np.nan))
