"""The road world (docs/protocol.md §1): lanes of traffic and a wall-bouncing goal, generated a whole episode at a time.

The world does not depend on the agent, so an episode's frames are a pure function of (config, seed, length)
and are produced up front with numpy: every obstacle is a row of arrays (spawn step, lane, speed), its position
at any frame is closed-form (x0 + v·age), and all (obstacle, frame) pixels are painted with one scatter. The
readable per-step simulation of the same rules lives in `dynplan.env.stepwise`; tests hold the two equal.

Randomness: the seed's `SeedSequence` is split into independent streams (layout, goal, traffic, speeds,
agent start). Traffic draws are laid out step-major, so the world of a seed does not depend on the episode
length: the first 203 frames of a 407-frame world are the 203-frame world.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

import numpy as np

from dynplan.arguments import Bounds, checked
from dynplan.env.config import AGENT_START_MARGIN, GOAL_VALUE, RoadConfig, spawn_probability

#: Number of goal headings: 1°, 46°, …, 316°.
GOAL_HEADINGS = 8
#: The goal's headings in degrees (y up, from the +x axis), one drawn per episode.
GOAL_HEADINGS_DEG = 1.0 + 45.0 * np.arange(GOAL_HEADINGS)
#: Each class draws its speed from this many evenly spaced values.
SPEED_CHOICES = 10


def round_px(x: np.ndarray | float) -> np.ndarray:
    """Continuous coordinate → pixel index, rounding halves up (monotone, unlike numpy's half-to-even)."""
    return np.floor(np.asarray(x) + 0.5).astype(np.int64)


@dataclass(frozen=True)
class Traffic:
    """Every obstacle of an episode, one row each, in spawn order (step-major, then lane).

    step:     (N,) world step at which it entered (1 … W+T−1; frame f is world step W+f)
    lane:     (N,) lane index into `Layout`
    x0:       (N,) column of its entry position (0 moving +x, W−1−length moving −x)
    velocity: (N,) signed pixels per step along x
    length:   (N,) body length in pixels
    value:    (N,) pixel value
    """

    step: np.ndarray
    lane: np.ndarray
    x0: np.ndarray
    velocity: np.ndarray
    length: np.ndarray
    value: np.ndarray

    def x_at_age(self, age: np.ndarray | int, index: np.ndarray | slice = slice(None)) -> np.ndarray:
        """Continuous x of the obstacles' left end `age` steps after entering (closed form: no float drift)."""
        return self.x0[index] + self.velocity[index] * age

    def entered_by(self, step: int) -> Traffic:
        """The obstacles that had entered the road by world step `step` (frame f is world step W + f)."""
        keep = self.step <= step
        return Traffic(*(getattr(self, name)[keep] for name in ("step", "lane", "x0", "velocity", "length", "value")))


@dataclass(frozen=True)
class Layout:
    """Per-lane assignment, fixed for the episode. rows, cls (class index), direction (±1): each (L,)."""

    rows: np.ndarray
    cls: np.ndarray
    direction: np.ndarray


@dataclass(frozen=True)
class World:
    """One episode of the road world.

    frames:      (T, H, W) uint8 world frames (no agent)
    goal:        (T, 2) float64 continuous (y, x) of the goal block's lower-left pixel
    agent_start: (2,) float64 (y, x) where the agent starts
    layout, traffic: how the frames were generated; None for a world read back from a log or built by hand
    """

    config: RoadConfig
    seed: int
    frames: np.ndarray
    goal: np.ndarray
    agent_start: np.ndarray
    layout: Layout | None = None
    traffic: Traffic | None = None

    @property
    def goal_px(self) -> np.ndarray:
        """(T, 2) int64 pixel (row, col) of the goal block's lower-left pixel in each frame."""
        return round_px(self.goal)


@dataclass(frozen=True)
class Draws:
    """All random draws of an episode, separated from how they are turned into frames.

    spawn_u: (S, L) uniforms, one per world step (1 … S) and lane; lane spawns when u < P(spawn)
    """

    layout: Layout
    goal_start: np.ndarray
    goal_velocity: np.ndarray
    agent_start: np.ndarray
    spawn_u: np.ndarray
    speed_rng: np.random.Generator


def draw(config: RoadConfig, seed: int, n_frames: int) -> Draws:
    """Draw an episode's randomness from `seed`; each kind from its own stream (see module docstring)."""
    if not isinstance(seed, int | np.integer) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    layout_rng, goal_rng, traffic_rng, speed_rng, agent_rng = (
        np.random.default_rng(s) for s in np.random.SeedSequence(int(seed)).spawn(5)
    )
    H, W = config.height, config.width
    rows = config.lanes
    n_classes = len(config.classes)
    cls = np.empty(len(rows), dtype=np.int64)
    cls[layout_rng.permutation(len(rows))] = np.arange(len(rows)) % n_classes
    direction = np.where(layout_rng.random(len(rows)) < 0.5, 1, -1).astype(np.int64)

    goal_start = goal_rng.uniform((0.0, 0.0), (H - 2, W - 2))
    goal_velocity = goal_velocities(config, GOAL_HEADINGS_DEG[goal_rng.integers(GOAL_HEADINGS)])

    start_row = 0 if agent_rng.random() < 0.5 else H - 2
    start_col = agent_rng.integers(AGENT_START_MARGIN, W - AGENT_START_MARGIN)
    agent_start = np.array([start_row, start_col], dtype=np.float64)

    n_steps = W + n_frames - 1
    spawn_u = traffic_rng.random((n_steps, len(rows)))
    return Draws(Layout(rows, cls, direction), goal_start, goal_velocity, agent_start, spawn_u, speed_rng)


def spawn_traffic(config: RoadConfig, draws: Draws) -> Traffic:
    """Turn the spawn draws into the table of obstacles (Poisson rule: spawn when k ~ Poisson(3.5·len) < level)."""
    classes = config.classes
    lanes = draws.layout
    p_lane = np.array([spawn_probability(classes[c].length, config.level) for c in lanes.cls])
    step_idx, lane = np.nonzero(draws.spawn_u < p_lane)
    cls = lanes.cls[lane]
    lengths = np.array([c.length for c in classes])[cls]
    speed_table = np.array([c.speeds for c in classes])
    speed = speed_table[cls, draws.speed_rng.integers(0, SPEED_CHOICES, size=len(lane))]
    direction = lanes.direction[lane]
    x0 = np.where(direction > 0, 0, config.width - 1 - lengths).astype(np.float64)
    return Traffic(
        step=step_idx + 1,
        lane=lane,
        x0=x0,
        velocity=direction * speed,
        length=lengths,
        value=np.array([c.value for c in classes])[cls],
    )


def goal_track(config: RoadConfig, draws: Draws, n_frames: int) -> np.ndarray:
    """(T, 2) goal positions: straight motion folded into the box [0, H−2] × [0, W−2] (mirror reflection)."""
    world_steps = config.width + np.arange(n_frames)
    return fold_goal(config, draws.goal_start + world_steps[:, None] * draws.goal_velocity)


def goal_velocities(config: RoadConfig, heading_deg: np.ndarray | float) -> np.ndarray:
    """(…, 2) the goal's velocity (dy, dx) at each heading (degrees from the +x axis, y up)."""
    heading = np.deg2rad(np.asarray(heading_deg, dtype=np.float64))
    return config.goal_speed * np.stack([np.sin(heading), np.cos(heading)], axis=-1)


def goal_box(config: RoadConfig) -> np.ndarray:
    """(2,) the far corner (H−2, W−2) of the box [0, H−2] × [0, W−2] the goal block's lower-left corner moves in."""
    return np.array([config.height - 2, config.width - 2], dtype=np.float64)


def fold_goal(config: RoadConfig, unfolded: np.ndarray) -> np.ndarray:
    """(…, 2) straight-line goal positions folded into `goal_box` by mirror reflection at its walls — the goal's
    bounces. Folding a folded position moved along its folded velocity is folding the line."""
    span = goal_box(config)
    m = np.mod(unfolded, 2 * span)
    return np.where(m > span, 2 * span - m, m)


def paint(config: RoadConfig, layout: Layout, traffic: Traffic, goal: np.ndarray) -> np.ndarray:
    """Render (T, H, W) uint8 frames: the goal first, obstacles over it."""
    H, W = config.height, config.width
    T = len(goal)
    frames = np.zeros((T, H, W), dtype=np.uint8)

    gy, gx = round_px(goal).T
    t = np.arange(T)
    frames[t[:, None, None], gy[:, None, None] + np.arange(2)[:, None], gx[:, None, None] + np.arange(2)] = GOAL_VALUE

    # Visible frames of each obstacle: from frame 0 (or its spawn) until its body has surely left the grid.
    speed = np.abs(traffic.velocity)
    age_lo = np.maximum(0, W - traffic.step)
    age_hi = np.minimum(np.ceil((W + traffic.length) / speed).astype(np.int64), T - 1 + W - traffic.step)
    count = np.maximum(age_hi - age_lo + 1, 0)
    obstacle = np.repeat(np.arange(len(count)), count)
    age = age_lo[obstacle] + np.arange(len(obstacle)) - np.repeat(np.cumsum(count) - count, count)
    frame = traffic.step[obstacle] + age - W
    left = round_px(traffic.x_at_age(age, obstacle))

    max_len = int(traffic.length.max(initial=1))
    cols = left[:, None] + np.arange(max_len)
    visible = (np.arange(max_len) < traffic.length[obstacle][:, None]) & (cols >= 0) & (cols < W)
    row_start = (frame * H + layout.rows[traffic.lane[obstacle]]) * W
    pixels = (row_start[:, None] + cols)[visible]
    values = np.broadcast_to(traffic.value[obstacle][:, None], cols.shape)[visible]
    frames.reshape(-1)[pixels] = values
    return frames


@checked
def generate_world(
    config: RoadConfig | None = None,
    seed: Annotated[int, Bounds(0, 2**64 - 1)] = 0,
    n_frames: Annotated[int, Bounds(1, 10**7)] | None = None,
) -> World:
    """Generate one episode of `n_frames` frames (default T for the config's agent speed) from `seed`."""
    config = config or RoadConfig()
    n_frames = config.max_steps if n_frames is None else n_frames
    draws = draw(config, seed, n_frames)
    traffic = spawn_traffic(config, draws)
    goal = goal_track(config, draws, n_frames)
    frames = paint(config, draws.layout, traffic, goal)
    return World(config, int(seed), frames, goal, draws.agent_start, draws.layout, traffic)
