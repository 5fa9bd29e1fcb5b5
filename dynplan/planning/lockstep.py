"""Episodes in lockstep, for every world: at each step one batched prediction for all the episodes that predict
(`predict_together`), then each decides on its own prediction and steps.

A world's episode brings what the loop asks of it (`LockstepEpisode`): its forward model (None: it predicts
nothing, e.g. a technique that reads the true future or does not plan), the frames it has observed, how many
frames ahead it asks for, and its decision and step given its prediction and its share of the batch's time. The
road's `run_episodes` is this loop over its episodes, and so is each other world's lockstep (a world's package).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

import numpy as np

from dynplan.planning.forward import ForwardModel, Prediction, predict_together


class LockstepEpisode(Protocol):
    """One episode of a lockstep batch, as the loop sees it."""

    model: ForwardModel | None

    def observed(self) -> np.ndarray:
        """The frames observed so far, (t + 1, H, W) uint8 (or the last of them, as many as the model reads)."""
        ...

    def asks(self) -> int:
        """How many frames ahead its prediction holds."""
        ...

    def advance(self, prediction: Prediction | None, share_ms: float) -> bool:
        """Decide on `prediction` (None without a model; `share_ms`: its share of the batch's prediction time) and
        step; whether the episode still plays."""
        ...


def step_together(episodes: Sequence[LockstepEpisode]) -> list[bool]:
    """One step of every episode: the predictions of those with a model in one `predict_together` (one batched
    call per group of models on the same weights), then each advances in order. Whether each still plays."""
    asking = [e for e in episodes if e.model is not None]
    predicted, spent = predict_together(
        [e.model for e in asking], [e.observed() for e in asking], [e.asks() for e in asking]
    )
    shares = {id(e): (p, ms) for e, p, ms in zip(asking, predicted, spent, strict=True)}
    return [e.advance(*shares.get(id(e), (None, 0.0))) for e in episodes]
