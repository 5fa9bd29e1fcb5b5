"""The road world simulated one step at a time, the way docs/protocol.md §1 tells it.

A deliberately plain re-statement of the rules: a list of live obstacles that move, leave and enter each step,
and a goal whose velocity component flips when it would leave the box. It consumes the same random draws as
`dynplan.env.road`, so the tests can hold the vectorised generator to it frame for frame, and the `world`
benchmark uses it as its baseline. Not for production use: it is ~25× slower (`python -m dynplan.bench world`).
"""

from __future__ import annotations

import numpy as np

from dynplan.env.config import GOAL_VALUE, RoadConfig, spawn_probability
from dynplan.env.road import SPEED_CHOICES, draw, goal_box, round_px


def simulate_world(config: RoadConfig, seed: int, n_frames: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Return (frames (T, H, W) uint8, goal (T, 2) float64) for `seed`, stepping the world one step at a time."""
    n_frames = config.max_steps if n_frames is None else n_frames
    H, W = config.height, config.width
    draws = draw(config, seed, n_frames)
    classes = config.classes
    lanes = draws.layout
    p_spawn = [spawn_probability(classes[c].length, config.level) for c in lanes.cls]

    live: list[dict] = []
    goal = draws.goal_start.copy()
    goal_velocity = draws.goal_velocity.copy()
    span = goal_box(config)
    frames = np.zeros((n_frames, H, W), dtype=np.uint8)
    goals = np.zeros((n_frames, 2))

    for step in range(1, W + n_frames):
        # Obstacles move (position from age: no float drift), then leave once the whole body is outside.
        for ob in live:
            ob["age"] += 1
            ob["x"] = ob["x0"] + ob["v"] * ob["age"]
        live = [ob for ob in live if round_px(ob["x"]) <= W - 1 and round_px(ob["x"]) + ob["length"] - 1 >= 0]

        # New obstacles enter at their lane's entry edge.
        for lane in range(len(lanes.rows)):
            if draws.spawn_u[step - 1, lane] < p_spawn[lane]:
                cls = classes[lanes.cls[lane]]
                speed = cls.speeds[int(draws.speed_rng.integers(0, SPEED_CHOICES))]
                direction = int(lanes.direction[lane])
                x0 = 0.0 if direction > 0 else float(W - 1 - cls.length)
                live.append(
                    dict(
                        row=int(lanes.rows[lane]),
                        x0=x0,
                        x=x0,
                        v=direction * speed,
                        age=0,
                        length=cls.length,
                        value=cls.value,
                    )
                )

        goal = _reflect(goal + goal_velocity, goal_velocity, span)

        t = step - W
        if t >= 0:
            gy, gx = round_px(goal)
            frames[t, gy : gy + 2, gx : gx + 2] = GOAL_VALUE
            for ob in live:
                left = int(round_px(ob["x"]))
                lo, hi = max(left, 0), min(left + ob["length"], W)
                frames[t, ob["row"], lo:hi] = ob["value"]
            goals[t] = goal
    return frames, goals


def _reflect(goal: np.ndarray, velocity: np.ndarray, span: np.ndarray) -> np.ndarray:
    """The goal after a move, reflected off the walls so that it stays fully inside (`velocity` flips in place)."""
    for axis in range(2):
        if goal[axis] > span[axis]:
            goal[axis] = 2 * span[axis] - goal[axis]
            velocity[axis] = -velocity[axis]
        elif goal[axis] < 0:
            goal[axis] = -goal[axis]
            velocity[axis] = -velocity[axis]
    return goal
