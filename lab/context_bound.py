"""The context bound: how well any point prediction from the last N frames can place the obstacles on the road.

The floor (`dynplan.evaluation.prediction.foreseeable_frames`) assumes the obstacles already on the road are
known exactly. A model sees them only as pixels: an obstacle's left end is its continuous position rounded, so
N frames leave its speed (one of its class's `SPEED_CHOICES`) and its sub-pixel phase (its age) uncertain — a
0.2 px/step truck can sit still for all of four frames. `ContextBoundModel` keeps, for each obstacle on the road
at the decision, every (speed, age) consistent with its rounded positions (and its absence before it entered)
over the last N frames, and places it where most of them put it at each step ahead. It is told which pixels
belong to which obstacle, so it bounds what a model of N frames can do with one future. The goal is bounded
the same way: every (sub-pixel position, folded velocity) whose rounded blocks over the last N frames match the
goal's, the block drawn where most of them put it (`goal_placements`).
"""

from __future__ import annotations

import numpy as np

from dynplan.env.config import FREE, RoadConfig
from dynplan.env.road import GOAL_HEADINGS_DEG, World, fold_goal, goal_box, goal_velocities, paint, round_px
from dynplan.planning.forward import Prediction

#: Sub-pixel positions per pixel and axis among the goal's hypotheses.
GOAL_GRID = 512


def folded_goal_velocities(config: RoadConfig) -> np.ndarray:
    """(V, 2) every velocity (dy, dx) the goal can have between bounces: each heading's, with either component's sign
    flipped by a wall (16 distinct ones on the default headings)."""
    speeds = np.abs(goal_velocities(config, GOAL_HEADINGS_DEG))
    signs = np.array([(1, 1), (1, -1), (-1, 1), (-1, -1)], dtype=np.float64)
    return np.unique((signs[:, None] * speeds[None]).reshape(-1, 2).round(12), axis=0)


class ContextBoundModel:
    """Each obstacle on the road at the decision placed by its most probable position given the last `context`
    frames (uniform over its class's speeds and its age); obstacles that enter later are not predicted.
    `occupancy` > 0 also draws every pixel that at least that share of its hypotheses cover: the fewest false
    positives a view of N frames needs for its misses (as the world model's occupancy threshold does)."""

    def __init__(self, world: World, context: int, occupancy: float = 0.0):
        if world.traffic is None or world.layout is None:
            raise ValueError("the context bound needs a generated world (its traffic table); this one was read back")
        if not isinstance(context, int | np.integer) or context < 1:
            raise ValueError(f"context must be a whole number of frames >= 1, got {context!r}")
        if not 0.0 <= occupancy < 1.0:
            raise ValueError(f"occupancy must be in [0, 1) (0: the most probable placement only), got {occupancy!r}")
        self.world, self.context, self.occupancy = world, int(context), float(occupancy)
        self.name = self.label(self.context, self.occupancy)
        traffic, layout = world.traffic, world.layout
        speeds = np.array([c.speeds for c in world.config.classes])
        self._speeds = speeds[layout.cls[traffic.lane]]  # (N obstacles, SPEED_CHOICES)
        width, longest = world.config.width, int(traffic.length.max(initial=1))
        self._ages = np.arange(int(np.ceil((width + longest) / speeds.min())) + 2)

    @staticmethod
    def label(context: int, occupancy: float = 0.0) -> str:
        """The bound's name in tables and figures."""
        return f"context bound, {context} frame" + "s" * (context != 1) + f", occupancy {occupancy:g}" * (occupancy > 0)

    def hypotheses(self, t: int, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For the obstacles on the road at frame t (their indices, O): which (speed, age at t) hypotheses their
        rounded positions over the context allow ((O, S, A) bool) and each one's left end at t+1 … t+k."""
        traffic, width = self.world.traffic, self.world.config.width
        age_t = width + t - traffic.step
        left_t = round_px(traffic.x_at_age(np.maximum(age_t, 0)))
        on_road = np.flatnonzero((age_t >= 0) & (left_t > -traffic.length) & (left_t < width))
        frames = np.arange(max(0, t - self.context + 1), t + 1)
        back = t - frames  # (J,) steps before the decision
        true_age = age_t[on_road, None] - back  # (O, J)
        true_left = round_px(traffic.x_at_age(np.maximum(true_age, 0), on_road[:, None]))
        sign = np.sign(traffic.velocity[on_road])[:, None, None]
        x0 = traffic.x0[on_road, None, None]
        speed = self._speeds[on_road][:, :, None]  # (O, S, 1)
        ages = self._ages[None, None, :]  # age at the decision

        def left(after: np.ndarray | int) -> np.ndarray:
            return round_px(x0[..., None] + sign[..., None] * speed[..., None] * (ages[..., None] + after))

        hyp_age = ages[..., None] - back  # (1, 1, A, J)
        present = hyp_age >= 0
        consistent = np.all(
            (present == (true_age >= 0)[:, None, None, :]) & (~present | (left(-back) == true_left[:, None, None, :])),
            axis=-1,
        )  # (O, S, A)
        return on_road, consistent, left(np.arange(1, k + 1))  # (O, S, A, k) left ends ahead

    def placements(self, t: int, k: int) -> tuple[np.ndarray, np.ndarray]:
        """(indices of the obstacles on the road at frame t, (len, k) their most probable left ends at t+1 … t+k)."""
        on_road, consistent, ahead = self.hypotheses(t, k)
        return on_road, self._modes(self._spreads(consistent, ahead))

    @staticmethod
    def _spreads(consistent: np.ndarray, ahead: np.ndarray) -> list[list[tuple[np.ndarray, np.ndarray]]]:
        """Per obstacle and step ahead: the left ends its consistent hypotheses give, and each one's share."""
        spreads = []
        for o in range(len(consistent)):
            candidates = ahead[o][consistent[o]]  # (hypotheses, k)
            steps = [np.unique(candidates[:, h], return_counts=True) for h in range(candidates.shape[1])]
            spreads.append([(values, counts / len(candidates)) for values, counts in steps])
        return spreads

    @staticmethod
    def _modes(spreads: list[list[tuple[np.ndarray, np.ndarray]]]) -> np.ndarray:
        """(obstacles, k) the left end most hypotheses give at each step ahead."""
        return np.array([[values[np.argmax(shares)] for values, shares in steps] for steps in spreads],
                        dtype=np.int64).reshape(len(spreads), -1)  # fmt: skip

    def goal_shares(self, t: int, k: int) -> np.ndarray:
        """(k, H − 1, W − 1) the share of the goal's hypotheses that put its block's lower-left pixel at each place at
        t+1 … t+k. A hypothesis is a folded velocity and a position at t on a 1/`GOAL_GRID` px grid whose rounded
        blocks over the context match the goal's, all alike in weight; the axes fold and round apart, so each
        velocity's hypotheses are a product of one grid per axis. All zero only where every grid point misses a
        rounding edge the true position sits on."""
        config, seen, span = self.world.config, self.world.goal_px, goal_box(self.world.config)
        grid = seen[t] + (np.arange(GOAL_GRID)[:, None] + 0.5) / GOAL_GRID - 0.5  # (G, 2): one grid per axis
        inside = (grid >= 0) & (grid <= span)  # a folded position lies in the box
        back = t - np.arange(max(0, t - self.context + 1), t + 1)  # (J,) steps before the decision
        shares = np.zeros((k, *(span.astype(int) + 1)))
        for velocity in folded_goal_velocities(config):
            past = round_px(fold_goal(config, grid[:, None] - back[:, None] * velocity))  # (G, J, 2)
            consistent = inside & np.all(past == seen[t - back], axis=1)  # (G, 2)
            if not consistent.any(axis=0).all():
                continue
            ahead = round_px(fold_goal(config, grid[:, None] + np.arange(1, k + 1)[:, None] * velocity))  # (G, k, 2)
            for h in range(k):
                rows = np.bincount(ahead[consistent[:, 0], h, 0], minlength=shares.shape[1])
                cols = np.bincount(ahead[consistent[:, 1], h, 1], minlength=shares.shape[2])
                shares[h] += np.outer(rows, cols)
        total = shares.sum(axis=(1, 2), keepdims=True)
        return np.divide(shares, total, out=np.zeros_like(shares), where=total > 0)

    def goal_placements(self, t: int, k: int) -> np.ndarray:
        """(k, 2) the goal block most of its hypotheses give at t+1 … t+k (its last block where none is left)."""
        places = goal_box(self.world.config).astype(int) + 1
        shares = self.goal_shares(t, k).reshape(k, places.prod())
        blocks = np.stack(np.unravel_index(shares.argmax(axis=1), places), axis=1)
        blocks[shares.max(axis=1, initial=0) == 0] = self.world.goal_px[t]
        return blocks

    def predict(self, observed: np.ndarray, k: int) -> Prediction:
        world, t = self.world, len(observed) - 1
        config, layout, traffic = world.config, world.layout, world.traffic
        k = min(k, len(world.goal) - t - 1)
        goal = self.goal_placements(t, k).astype(np.float64)
        frames = paint(config, layout, traffic.entered_by(0), goal)  # the goal on an empty road
        on_road, consistent, ahead = self.hypotheses(t, k)
        spreads = self._spreads(consistent, ahead)
        for o, lefts in zip(on_road, self._modes(spreads), strict=True):
            cols = lefts[:, None] + np.arange(traffic.length[o])
            h, c = np.nonzero((cols >= 0) & (cols < config.width))
            frames[h, layout.rows[traffic.lane[o]], cols[h, c]] = traffic.value[o]
        if self.occupancy > 0:
            self._draw_occupied(frames, on_road, spreads)
        return Prediction.from_frames(frames)

    def _draw_occupied(self, frames: np.ndarray, on_road: np.ndarray, spreads: list) -> None:
        """Draw, where the road is free, each pixel covered by at least `occupancy` of an obstacle's hypotheses."""
        traffic, layout, width = self.world.traffic, self.world.layout, self.world.config.width
        for index, steps in zip(on_road, spreads, strict=True):
            length, row = int(traffic.length[index]), layout.rows[traffic.lane[index]]
            for h, (values, shares) in enumerate(steps):
                share = np.zeros(width)
                for value, part in zip(values, shares, strict=True):
                    share[max(value, 0) : max(value + length, 0)] += part
                cols = np.flatnonzero(share >= self.occupancy)
                free = cols[frames[h, row, cols] == FREE]
                frames[h, row, free] = traffic.value[index]
