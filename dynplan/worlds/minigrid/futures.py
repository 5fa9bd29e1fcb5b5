"""What MiniGrid's planner may assume of the balls' next frames: each technique's futures, (F, K + 1, H, W) frames
from the frame now (the first) over K steps.

- `oracle`: the true future (one).
- `stand_still`: the balls stay where they are (one).
- `constant_velocity`: each ball keeps its last step (one; a ball whose last step is not clear stays).
- `walk`: futures sampled from the balls' true move rule (each ball in turn to a uniformly random free cell of its
  3 × 3 neighbourhood; after 101 tries it stays) — the planner that knows the distribution the world draws from.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dynplan.worlds.minigrid.grid import PIXEL_VALUES

BALL, FLOOR = PIXEL_VALUES["ball"], PIXEL_VALUES["floor"]
#: Tries a ball's move gets before it stays (MiniGrid's `place_obj(max_tries=100)` tries 101 times).
TRIES = 101


def oracle(frames: np.ndarray, t: int, k: int) -> np.ndarray:
    """The recorded frames t … t + k (the last repeated past the episode's end)."""
    index = np.minimum(np.arange(t, t + k + 1), len(frames) - 1)
    return frames[index][None]


def stand_still(frames: np.ndarray, t: int, k: int) -> np.ndarray:
    """The frame now, k + 1 times."""
    return np.repeat(frames[t][None, None], k + 1, axis=1)


def _balls(frame: np.ndarray) -> np.ndarray:
    return np.argwhere(frame == BALL)


def constant_velocity(frames: np.ndarray, t: int, k: int) -> np.ndarray:
    """Each ball moved on by its last step (from the nearest ball of the frame before within a king's move; none:
    it stays), each step only onto the floor (else it stops)."""
    now = frames[t]
    background = np.where(now == BALL, FLOOR, now)
    future = np.repeat(background[None], k + 1, axis=0)
    before = _balls(frames[t - 1]) if t > 0 else np.empty((0, 2), int)
    for ball in _balls(now):
        velocity, cell = _last_step(ball, before), ball
        for j in range(k + 1):
            ahead = cell + velocity
            if j > 0 and background[ahead[0], ahead[1]] == FLOOR:
                cell = ahead
            future[j, cell[0], cell[1]] = BALL
    return future[None]


def _last_step(ball: np.ndarray, before: np.ndarray) -> np.ndarray:
    """The step that brought `ball` where it is: from the nearest of the balls `before` a king's move away."""
    steps = ball - before
    near = steps[np.abs(steps).max(axis=1, initial=0) <= 1] if len(steps) else steps
    near = near[np.abs(near).sum(axis=1) > 0] if len(near) else near
    return near[np.argmin(np.abs(near).sum(axis=1))] if len(near) else np.zeros(2, int)


def walk(frames: np.ndarray, t: int, k: int, samples: int, rng: np.random.Generator) -> np.ndarray:
    """`samples` futures of k steps drawn from the balls' move rule, from the frame now."""
    out = np.empty((samples, k + 1, *frames.shape[1:]), frames.dtype)
    out[:, 0] = frames[t]
    for s in range(samples):
        frame = frames[t].copy()
        for j in range(1, k + 1):
            frame = _walk_step(frame, rng)
            out[s, j] = frame
    return out


def _walk_step(frame: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One step of every ball, in MiniGrid's order of its balls (here: the frame's, bottom row first)."""
    frame = frame.copy()
    height, width = frame.shape
    for row, col in _balls(frame):
        for _ in range(TRIES):
            r, c = row + rng.integers(-1, 2), col + rng.integers(-1, 2)
            if 0 <= r < height and 0 <= c < width and frame[r, c] == FLOOR:
                frame[row, col], frame[r, c] = FLOOR, BALL
                break
    return frame


@dataclass(frozen=True)
class Imagined:
    """`samples` futures of k steps from the frame now: rooms (S, k + 1, H, W) uint8 and each cell's chance of a
    ball (S, k + 1, H, W) float32 — the first of each the frame now (its balls certain)."""

    rooms: np.ndarray
    balls: np.ndarray
