"""The agent's rules (docs/protocol.md §1): its eight actions, how it moves, and how a frame judges where it lands.

Pure functions over arrays, shared by the Gymnasium environment, the planner's rollouts and evaluation, so
that every part of dynplan agrees on what counts as death, goal and timeout.
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np

from dynplan.env.config import FREE, GOAL_VALUE
from dynplan.env.road import round_px

#: Headings of the 8 actions in degrees, in action-index order: −180°, −135°, …, 135°.
ACTION_ANGLES_DEG = np.arange(-180, 180, 45)
N_ACTIONS = len(ACTION_ANGLES_DEG)
#: The agent's first decision is at this frame index, having seen frames 0 … 4.
FIRST_DECISION_FRAME = 4

REWARD_GOAL = 20.0
REWARD_DEATH = -20.0


class Outcome(IntEnum):
    """What a frame says about the agent's position. RUNNING means neither goal nor death."""

    RUNNING = 0
    GOAL = 1
    DEATH = 2
    TIMEOUT = 3


def action_deltas(speed: float) -> np.ndarray:
    """(8, 2) displacement (dy, dx) = speed · (sin θ, cos θ) of each action; exact zeros on the axes."""
    theta = np.deg2rad(ACTION_ANGLES_DEG)
    unit = np.stack([np.sin(theta), np.cos(theta)], axis=1)
    unit[np.abs(unit) < 1e-12] = 0.0
    return speed * unit


def judge(frame: np.ndarray, position: np.ndarray) -> np.ndarray:
    """Outcome of standing at `position` (…, 2) on `frame` (H, W): DEATH off-grid or on an obstacle, GOAL on a
    goal pixel, else RUNNING. Broadcasts over leading position dimensions; returns int8 Outcome codes."""
    H, W = frame.shape
    px = round_px(position)
    y, x = px[..., 0], px[..., 1]
    inside = (y >= 0) & (y < H) & (x >= 0) & (x < W)
    value = frame[np.clip(y, 0, H - 1), np.clip(x, 0, W - 1)]
    outcome = np.full(y.shape, Outcome.RUNNING, dtype=np.int8)
    outcome[inside & (value == GOAL_VALUE)] = Outcome.GOAL
    outcome[~inside | ((value != FREE) & (value != GOAL_VALUE))] = Outcome.DEATH
    return outcome


def reward_of(outcome: Outcome | int) -> float:
    """+20 for the goal, −20 for death, 0 otherwise (timeout or still running)."""
    return {Outcome.GOAL: REWARD_GOAL, Outcome.DEATH: REWARD_DEATH}.get(Outcome(outcome), 0.0)
