"""Planning Freeway's chicken: an exact search of its rule over the predicted lanes.

The world does not depend on the chicken, so a decision's whole future is one array of lane frames (the frame now
and k predicted ones), and the planner simulates only the chicken (`dynplan.worlds.freeway.game.chicken_frames`, on each
step's frames as `step_frames` estimates them). Its state is small — a height and a timer — and it has three
actions, so the search is exhaustive rather than sampled: every action sequence of the horizon, with the sequences
that reach the same state after the same first action merged (at most 3 × 178 × 256 states a depth, a few hundred
in practice). Each first action is valued by the most crossings a plan starting with it makes within the horizon,
then by the height it ends at (a chicken still knocked back or stunned counts `STUN_PENALTY` pixels lower); the best
is played, UP before NOOP before DOWN on a tie.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from pydantic import Field

from dynplan.config import Config
from dynplan.worlds.freeway.game import ACTIONS, Chicken, chicken_frames, step_frames

#: Pixels a chicken still knocked back or stunned at the horizon counts lower: about the climb its stun costs.
STUN_PENALTY = 30
#: The order in which ties between first actions are broken: UP, NOOP, DOWN.
PREFERENCE = (1, 0, 2)


class ChickenSearch(Config):
    """The chicken's search: how many predicted steps it looks ahead."""

    horizon: int = Field(8, ge=1, le=64, description="horizon k: predicted frames the search consults")


@dataclass(frozen=True)
class ChickenDecision:
    """One decision: the action, each first action's value (crossings within the horizon, end height), the states
    searched and the search's milliseconds."""

    action: int
    crossings: np.ndarray
    height: np.ndarray
    states: int
    search_ms: float


def plan_chicken(chicken: Chicken, frames: np.ndarray, search: ChickenSearch | None = None) -> ChickenDecision:
    """The chicken's next action from `frames` (K + 1, H, W): the lanes now and the K predicted after them (the
    search looks min(K, horizon) steps ahead)."""
    search = search or ChickenSearch()
    depth = min(search.horizon, len(frames) - 1)
    if depth < 1:
        raise ValueError(
            f"frames holds {len(frames)} lane frames; the search needs the frame now and one more at least"
        )
    start = time.perf_counter()
    layer: dict[tuple[Chicken, int], float] = {(chicken, a): 0.0 for a in range(len(ACTIONS))}
    states = 0
    for d in range(depth):
        drawn = step_frames(frames[d], frames[d + 1])
        following: dict[tuple[Chicken, int], float] = {}
        for (state, first), reward in layer.items():
            for action in (first,) if d == 0 else range(len(ACTIONS)):
                after, gained = chicken_frames(state, action, drawn)
                key = (after, first)
                following[key] = max(following.get(key, -1.0), reward + gained)
        layer, states = following, states + len(following)
    crossings, height = np.full(len(ACTIONS), -1.0), np.full(len(ACTIONS), -np.inf)
    for (state, first), reward in layer.items():
        value = (reward, _height(state))
        if value > (crossings[first], height[first]):
            crossings[first], height[first] = value
    action = max(PREFERENCE, key=lambda a: (crossings[a], height[a], -PREFERENCE.index(a)))
    return ChickenDecision(action, crossings, height, states, (time.perf_counter() - start) * 1e3)


def _height(chicken: Chicken) -> float:
    return float(chicken.y - (STUN_PENALTY if chicken.knocked else 0))
