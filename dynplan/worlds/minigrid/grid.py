"""MiniGrid Dynamic-Obstacles' world without the agent: walls, a goal in the corner and balls in a random walk.

Farama's `minigrid` (the `minigrid` extra, imported only when a world is recorded) makes the episode: its
`DynamicObstaclesEnv` is reset with the episode's seed (walls, the goal at the bottom-right corner, the balls placed
around the agent's start), the agent is lifted off the grid, and each step runs the package's own ball loop — every
ball redrawn from its 3 × 3 neighbourhood by `place_obj` on the env's generator until a free cell comes up (after
101 tries it stays). The world so recorded does not depend on the agent, as dynplan's planning needs; in the
package's own game the agent's cell is refused too, so its balls would depend on where the agent walks.

A frame is the grid, one pixel a cell, row 0 at the bottom (MiniGrid's y grows downward): floor, wall, goal and
ball values (`PIXEL_VALUES`).
"""

from __future__ import annotations

from dataclasses import dataclass
from operator import add
from typing import Annotated

import numpy as np
from pydantic import Field

from dynplan.arguments import Bounds, checked
from dynplan.config import Config
from dynplan.extras import require

#: Each cell's pixel value by what it holds (viridis: violet floor, blue walls, green balls, yellow goal).
PIXEL_VALUES = {"floor": 0, "wall": 72, "ball": 144, "goal": 244}
#: The agent's actions: MiniGrid's first three (turn left, turn right, move forward).
ACTIONS = ("turn left", "turn right", "forward")
#: Where the agent starts, MiniGrid's (x, y), facing right.
AGENT_START = (1, 1)


class MiniGridConfig(Config):
    """The world: a `size` × `size` room (walls included) with `obstacles` balls, recorded for `steps` steps."""

    size: int = Field(16, ge=5, le=64, description="cells along a side, walls included")
    obstacles: int = Field(8, ge=1, le=64, description="balls in the room")
    steps: int = Field(256, ge=1, le=100_000, description="steps an episode lasts at most")

    @property
    def height(self) -> int:
        return self.size

    @property
    def width(self) -> int:
        return self.size

    @property
    def max_steps(self) -> int:
        """Frames of a recording: the start and each step."""
        return self.steps + 1


@dataclass(frozen=True)
class MiniGridWorld:
    """One recorded episode: frames (T, size, size) uint8 with row 0 the bottom, the goal's (row, column) at every
    frame (it does not move) and the agent's start (row, column)."""

    config: MiniGridConfig
    seed: int
    frames: np.ndarray
    goal: np.ndarray
    agent_start: np.ndarray


def cell(config: MiniGridConfig, x: int, y: int) -> np.ndarray:
    """MiniGrid's cell (x, y) as a frame's (row, column)."""
    return np.array([config.size - 1 - y, x])


def _frame(env) -> np.ndarray:
    """The env's grid as a frame: a value per cell by its object, row 0 at the bottom."""
    from minigrid.core.constants import OBJECT_TO_IDX

    kinds = env.grid.encode()[:, :, 0].T  # (y, x) of MiniGrid's object indices
    values = np.zeros(max(OBJECT_TO_IDX.values()) + 1, np.uint8)
    for name, value in PIXEL_VALUES.items():
        values[OBJECT_TO_IDX[name]] = value
    values[OBJECT_TO_IDX["empty"]] = PIXEL_VALUES["floor"]
    return np.flip(values[kinds], axis=0)


def _move_balls(env) -> None:
    """The package's ball loop (`DynamicObstaclesEnv.step`): each ball to a free cell of its 3 × 3 neighbourhood."""
    for ball in env.obstacles:
        old = ball.cur_pos
        top = tuple(map(add, old, (-1, -1)))
        try:
            env.place_obj(ball, top=top, size=(3, 3), max_tries=100)
            env.grid.set(old[0], old[1], None)
        except RecursionError:  # no free cell came up: the ball stays
            pass


@checked
def record_world(
    config: MiniGridConfig,
    seed: Annotated[int, Bounds(0, 2**62)],
    n_frames: Annotated[int, Bounds(1, 100_001)] | None = None,
) -> MiniGridWorld:
    """The episode of `seed`: the room as reset, then each step's ball moves; `n_frames` (default the config's
    `max_steps`) frames."""
    require("minigrid", "minigrid", "--world minigrid")
    from minigrid.envs import DynamicObstaclesEnv

    env = DynamicObstaclesEnv(size=config.size, n_obstacles=config.obstacles, agent_start_pos=AGENT_START)
    if env.n_obstacles != config.obstacles:
        raise ValueError(
            f"obstacles={config.obstacles} is invalid for size {config.size}: MiniGrid places at most "
            f"{env.n_obstacles} balls in it (size / 2 + 1)"
        )
    env.reset(seed=int(seed))
    env.agent_pos = (-1, -1)  # off the grid: the balls no longer avoid the agent's cell
    frames = [_frame(env)]
    for _ in range((n_frames or config.max_steps) - 1):
        _move_balls(env)
        frames.append(_frame(env))
    goal = cell(config, config.size - 2, config.size - 2)
    stacked = np.stack(frames)
    goals = np.tile(goal.astype(np.float64), (len(stacked), 1))
    return MiniGridWorld(config, int(seed), stacked, goals, cell(config, *AGENT_START).astype(np.float64))
