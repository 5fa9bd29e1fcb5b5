"""How well a decoded or predicted frame matches the truth, in the terms that matter to the planner."""

from __future__ import annotations

import numpy as np

from dynplan.env.config import GOAL_VALUE
from dynplan.world import DEFAULT_WORLD, world


def frame_errors(true: np.ndarray, predicted: np.ndarray, world_name: str = DEFAULT_WORLD) -> dict[str, float]:
    """Rates over frames (N, H, W) uint8 of the world `world_name` (obstacles: values that are not its clear
    ground; free: its background):

    fn_rate:    obstacle pixels decoded as free, as a fraction of obstacle pixels (the dangerous error)
    fp_rate:    free pixels decoded as obstacles, as a fraction of free pixels
    goal_exact: fraction of frames showing a goal whose goal pixels are reproduced exactly
    pixel_acc:  fraction of all pixels with exactly the right value
    """
    true, predicted, entry = np.asarray(true), np.asarray(predicted), world(world_name)
    true_obstacle, predicted_obstacle = ~np.isin(true, entry.clear), ~np.isin(predicted, entry.clear)
    true_free = true == entry.background
    has_goal = (true == GOAL_VALUE).any(axis=(-2, -1)) & entry.has_goal
    goal_same = ((true == GOAL_VALUE) == (predicted == GOAL_VALUE)).all(axis=(-2, -1))
    return {
        "fn_rate": float((true_obstacle & ~predicted_obstacle).sum() / max(true_obstacle.sum(), 1)),
        "fp_rate": float((true_free & predicted_obstacle).sum() / max(true_free.sum(), 1)),
        "goal_exact": float(goal_same[has_goal].mean()) if has_goal.any() else 1.0,
        "pixel_acc": float((true == predicted).mean()),
    }
