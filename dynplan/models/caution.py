"""How cautious the planner's view of a learned model's prediction is: the settings, and the plain functions that
apply them to predicted frames.

The paper plans on the greedy (argmax) future alone, with decoder samples merged in by the conservative union
(`merge_samples`). Two settings, each chosen on validation episodes (docs/design.md §5), make the frames more
cautious: `occupancy` adds the pixels the prior gives at least that probability of holding an obstacle
(`unsure_obstacles`), `margin` widens every predicted obstacle along its lane (`widen_obstacles`). The module
needs no torch: the results store reads the settings' names to know a row's provenance.

Shapes: frames (k, H, W) uint8 world frames (free 0, obstacles, goal 244); samples (n, k, H, W).
"""

from __future__ import annotations

import numpy as np
from pydantic import Field

from dynplan.config import Config, ConfigError
from dynplan.env.config import FREE, GOAL_VALUE
from dynplan.planning.forward import goal_centres

#: The value drawn where only the occupancy shows an obstacle: a sedan's, the commonest class (the planner sees
#: any value other than free and goal as an obstacle).
UNSURE_OBSTACLE = 144


class Caution(Config):
    """Beyond the paper: how a learned model's frames are made more cautious before the planner sees them (both
    off: the paper's argmax alone). A result records the settings that are on (`recorded`)."""

    occupancy: float = Field(
        0.0,
        ge=0.0,
        lt=1.0,
        description="obstacle probability from which the prior's "
        "unsure obstacles join the frames (0: off; needs patch-local codes)",
    )
    margin: int = Field(
        0, ge=0, le=4, description="pixels each predicted obstacle is widened by along its lane, both ways (0: off)"
    )

    def recorded(self) -> dict:
        """The settings that are on (what a result played with them records; an absent key means off)."""
        return {name: value for name, value in self.model_dump().items() if value}

    def check_fits(self, patch_local: bool, tokenizer: str) -> None:
        """The one home of "occupancy needs patch-local codes" (each code decodes to its own patch, so a code's
        probability is its patch's): a ConfigError naming the tokenizer otherwise."""
        if self.occupancy and not patch_local:
            raise ConfigError(
                f"occupancy={self.occupancy} needs a tokenizer with patch-local codes (local=True); "
                f"{tokenizer!r} has none (use occupancy=0)"
            )


def merge_samples(mid: np.ndarray, samples: np.ndarray) -> np.ndarray:
    """mid (k, H, W) and samples (n, k, H, W) uint8 → the conservative frames (k, H, W) the planner sees: the
    largest obstacle value wherever any view shows one, and the goal at the median of the goals they show."""
    views = np.concatenate([mid[None], samples])  # (n + 1, k, H, W)
    obstacles = np.where((views != FREE) & (views != GOAL_VALUE), views, 0).max(axis=0)
    merged = np.zeros_like(mid)
    k, H, W = mid.shape
    centres = goal_centres(views.reshape(-1, H, W)).reshape(len(views), k, 2)  # NaN where no goal
    for t in range(k):
        found = centres[:, t][~np.isnan(centres[:, t, 0])]
        if len(found):
            # The block's centre is its lower-left pixel + 0.5: rounding (centre − 0.5) is flooring the centre.
            y, x = np.floor(np.median(found, axis=0)).astype(int)
            y, x = min(max(y, 0), H - 2), min(max(x, 0), W - 2)
            merged[t, y : y + 2, x : x + 2] = GOAL_VALUE
    return np.where(obstacles > 0, obstacles, merged)


def widen_obstacles(frames: np.ndarray, margin: int) -> np.ndarray:
    """frames (..., H, W) uint8 with every obstacle pixel also drawn on the `margin` pixels either side of it in its
    row (the largest obstacle value where several reach; over free road and goal alike)."""
    obstacles = np.where((frames != FREE) & (frames != GOAL_VALUE), frames, 0)
    widened = obstacles.copy()
    for shift in range(1, margin + 1):
        np.maximum(widened[..., shift:], obstacles[..., :-shift], out=widened[..., shift:])
        np.maximum(widened[..., :-shift], obstacles[..., shift:], out=widened[..., :-shift])
    return np.where(widened > 0, widened, frames)


def unsure_obstacles(probability: np.ndarray, occupancy: float) -> np.ndarray:
    """(k, H, W) uint8 frames of the unsure obstacles: `UNSURE_OBSTACLE` where the obstacle `probability`
    (k, H, W) reaches `occupancy`, free elsewhere."""
    return np.where(probability >= occupancy, UNSURE_OBSTACLE, FREE).astype(np.uint8)
