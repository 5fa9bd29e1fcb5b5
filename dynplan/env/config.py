"""Configuration of the road world and its agent (docs/protocol.md §1), validated in one place.

`RoadConfig` is the single source of truth for world geometry, traffic level and agent speed; see
`dynplan.config.Config` for how values are validated and serialised.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pydantic import Field

from dynplan.config import Config

# Pixel values of the world frame. The agent is not part of the world; it is drawn only when rendering.
FREE = 0
GOAL_VALUE = 244
AGENT_VALUE = 200


#: The agent starts in a column drawn from [AGENT_START_MARGIN, W - AGENT_START_MARGIN).
AGENT_START_MARGIN = 6


@dataclass(frozen=True)
class ObstacleClass:
    """One class of traffic: its pixel value, body length (pixels) and the speeds (pixels/step) it draws from."""

    name: str
    value: int
    length: int
    speeds: tuple[float, ...]


def obstacle_classes(width: int) -> tuple[ObstacleClass, ...]:
    """The five obstacle classes for a world `width` pixels wide, in the order lanes are dealt to them.

    Lengths scale with the width through m = max(int(0.15·W), 5) (7 at W = 48); each class draws its speed from
    10 evenly spaced values.
    """
    m = max(int(0.15 * width), 5)

    def speeds(lo: float, hi: float) -> tuple[float, ...]:
        return tuple(float(v) for v in np.linspace(lo, hi, 10))

    # Dealing order (the reference's effective order): tesla, wagon, sport, truck, sedan.
    return (
        ObstacleClass("tesla", 100, max(m - 2, 2), speeds(0.6, 1.3)),
        ObstacleClass("wagon", 85, max(m - 1, 3), speeds(0.3, 0.82)),
        ObstacleClass("sport", 130, max(m - 3, 2), speeds(1.3, 2.0)),
        ObstacleClass("truck", 45, m, speeds(0.2, 0.5)),
        ObstacleClass("sedan", 144, max(m - 4, 3), speeds(1.0, 2.3)),
    )


def lane_rows(height: int) -> np.ndarray:
    """Rows that carry traffic: 2 … H/2−2 and H/2+1 … H−3 (42 lanes at H = 48); all others stay free."""
    half = height // 2
    return np.concatenate([np.arange(2, half - 1), np.arange(half + 1, height - 2)])


def spawn_probability(length: int, level: int) -> float:
    """P(k < level) for k ~ Poisson(3.5·length): the per-lane, per-step chance that an obstacle enters."""
    lam = 3.5 * length
    return float(sum(math.exp(-lam) * lam**k / math.factorial(k) for k in range(level)))


def episode_frames(height: int, width: int, agent_speed: float) -> int:
    """Frames in an episode, T = int(3·√(H²+W²) / agent_speed): 203 at speed 1.0 and 407 at 0.5 on 48 × 48."""
    return int(3 * math.sqrt(height**2 + width**2) / agent_speed)


class RoadConfig(Config):
    """The road world and its agent. Defaults are the paper's experiments (48 × 48, level 6, the 2× agent)."""

    # H >= 11 gives the 5 lanes the layout needs (one per class); W >= 13 leaves room for the agent's start
    # columns [6, W-6) and for the longest obstacle.
    height: int = Field(48, ge=11, le=1024, description="grid rows H (pixels); row 0 is the bottom")
    width: int = Field(48, ge=2 * AGENT_START_MARGIN + 1, le=1024, description="grid columns W (pixels)")
    level: int = Field(6, ge=0, le=100, description="traffic level: a lane spawns when Poisson(3.5·len) < level")
    agent_speed: float = Field(1.0, gt=0.0, le=8.0, description="agent pixels per step: 1.0 = paper's 2×, 0.5 = 1×")
    goal_speed: float = Field(0.5, gt=0.0, le=8.0, description="goal pixels per step")

    @property
    def max_steps(self) -> int:
        """T, the number of frames in an episode for this agent speed."""
        return episode_frames(self.height, self.width, self.agent_speed)

    @property
    def classes(self) -> tuple[ObstacleClass, ...]:
        return obstacle_classes(self.width)

    @property
    def lanes(self) -> np.ndarray:
        return lane_rows(self.height)

    @property
    def obstacle_values(self) -> tuple[int, ...]:
        return tuple(c.value for c in self.classes)
