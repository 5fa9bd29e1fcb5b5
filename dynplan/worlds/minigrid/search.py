"""MiniGrid's planner: every action sequence of the horizon judged against every future it is given, with a value
that weighs the chance of dying.

A sequence's value in one future: 1 on reaching the goal, −1 on dying, and otherwise how near it ends to the goal
(its distance in steps, turns included, over the room's span, in (−1, 0]). Its value over the futures is the mean,
less `risk` times the fraction of futures it dies in; an action's value is that of its best sequence. One future
(the true one, or a guess) makes the search exact for it; sampled futures make it plan against their spread.
"""

from __future__ import annotations

import itertools
import time
from dataclasses import dataclass
from functools import cache

import numpy as np
from pydantic import Field

from dynplan.config import Config
from dynplan.worlds.minigrid.agent import FORWARD, HEADINGS, LEFT, RIGHT, Pose, roll_chances
from dynplan.worlds.minigrid.grid import PIXEL_VALUES

BALL, FLOOR = PIXEL_VALUES["ball"], PIXEL_VALUES["floor"]
#: Ties between first actions go to moving on, then to turning left.
PREFERENCE = (FORWARD, LEFT, RIGHT)


class GridSearch(Config):
    """How far the search looks and how much it fears dying."""

    horizon: int = Field(5, ge=1, le=8, description="horizon k: steps of each sequence (3^k sequences)")
    risk: float = Field(1.0, ge=0.0, le=100.0, description="weight of the fraction of futures a sequence dies in")
    commit: int = Field(
        5,
        ge=1,
        le=8,
        description="steps the agent commits to whatever the future (past them, "
        "each future's best continuation: the agent replans as it sees the balls move)",
    )


@dataclass(frozen=True)
class GridDecision:
    """One decision: the action, each first action's value and fraction of futures it dies in, and its ms."""

    action: int
    values: np.ndarray
    deaths: np.ndarray
    search_ms: float


@cache
def sequences(k: int) -> np.ndarray:
    """Every sequence of k actions, (3^k, k)."""
    return np.array(list(itertools.product(range(3), repeat=k)), np.int64)


def distance(poses: np.ndarray, goal: np.ndarray) -> np.ndarray:
    """Steps from each pose (..., 3) to the goal cell (row, column) in an open room: the cells between them and the
    turns to face the way there (one if the goal is to a side, two if behind)."""
    offset = goal - poses[..., :2]
    ahead = (HEADINGS[poses[..., 2]] * offset).sum(axis=-1)
    sideways = np.abs(offset).sum(axis=-1) - np.abs(ahead)
    turns = np.where(ahead < 0, 2, np.where(sideways > 0, 1, 0))
    return np.abs(offset).sum(axis=-1) + turns * (np.abs(offset).sum(axis=-1) > 0)


def layout_of(frame: np.ndarray) -> np.ndarray:
    """The room's walls and goal, which do not move: `frame` (H, W) with its balls taken off."""
    return np.where(frame == BALL, FLOOR, frame)


def plan_grid(pose: Pose, futures: np.ndarray, goal: np.ndarray, search: GridSearch | None = None) -> GridDecision:
    """The agent's next action from `futures` (F, K + 1, H, W): F futures of the frame now and K after it."""
    return plan_chances(pose, layout_of(futures[0, 0]), (futures == BALL).astype(np.float32), goal, search)


def plan_chances(
    pose: Pose, layout: np.ndarray, balls: np.ndarray, goal: np.ndarray, search: GridSearch | None = None
) -> GridDecision:
    """The agent's next action from futures of chances: `balls` (F, K + 1, H, W), each cell's chance of a ball now
    and at each of K steps in each future, in a room of `layout` (H, W, its walls and goal). A sequence's value in a
    future is its expected value there, and it dies there with its chance of dying."""
    search = search or GridSearch()
    start = time.perf_counter()
    k = min(search.horizon, balls.shape[1] - 1)
    if k < 1:
        raise ValueError(f"futures hold {balls.shape[1]} frames; the search needs the frame now and one more")
    seqs = sequences(k)
    rolled = roll_chances(pose, seqs, layout, balls[:, : k + 1])
    near = -np.minimum(distance(rolled.poses, goal) / (2.0 * layout.shape[-1]), 1.0)
    value = rolled.won - rolled.died + (1.0 - rolled.won - rolled.died) * near
    commit = min(search.commit, k)
    prefixes = seqs[:, :commit] @ (3 ** np.arange(commit)[::-1])
    futures = np.arange(balls.shape[0])
    values, deaths = np.full(3, -np.inf), np.ones(3)
    for prefix in range(3**commit):
        members = np.flatnonzero(prefixes == prefix)
        best = members[value[members].argmax(axis=0)]  # each future's best continuation of the prefix
        died = float(rolled.died[best, futures].mean())
        score = float(value[best, futures].mean()) - search.risk * died
        first = prefix // 3 ** (commit - 1)
        if score > values[first]:
            values[first], deaths[first] = score, died
    action = max(PREFERENCE, key=lambda a: (values[a], -PREFERENCE.index(a)))
    return GridDecision(action, values, deaths, (time.perf_counter() - start) * 1e3)
