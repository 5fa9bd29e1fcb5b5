"""The road world's dynamics: invariants over seeds, levels and grid sizes, golden statistics (docs/protocol.md §1)."""

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from dynplan.env import GOAL_VALUE, RoadConfig, generate_world
from dynplan.env.config import lane_rows, spawn_probability
from dynplan.env.stepwise import simulate_world

seeds = st.integers(0, 2**32 - 1)
configs = st.builds(
    RoadConfig,
    height=st.integers(11, 64),
    width=st.integers(13, 64),
    level=st.integers(0, 12),
    agent_speed=st.sampled_from([0.5, 1.0, 2.0]),
)


def obstacle_mask(frames: np.ndarray) -> np.ndarray:
    return (frames != 0) & (frames != GOAL_VALUE)


@given(configs, seeds)
def test_length_formula_determinism_and_prefix_independent_of_length(cfg, seed):
    a = generate_world(cfg, seed)
    b = generate_world(cfg, seed)
    assert a.frames.shape == (int(3 * math.sqrt(cfg.height**2 + cfg.width**2) / cfg.agent_speed), cfg.height, cfg.width)
    np.testing.assert_array_equal(a.frames, b.frames)
    np.testing.assert_array_equal(a.agent_start, b.agent_start)
    longer = generate_world(cfg, seed, n_frames=2 * cfg.max_steps + 1)
    np.testing.assert_array_equal(longer.frames[: cfg.max_steps], a.frames)
    np.testing.assert_array_equal(longer.goal[: cfg.max_steps], a.goal)


def test_paper_episode_lengths_share_a_recording():
    slow, fast = generate_world(RoadConfig(agent_speed=0.5), 7), generate_world(RoadConfig(agent_speed=1.0), 7)
    assert slow.frames.shape == (407, 48, 48) and fast.frames.shape == (203, 48, 48)
    np.testing.assert_array_equal(slow.frames[:203], fast.frames)
    assert slow.frames.dtype == np.uint8


def test_different_seeds_differ():
    worlds = [generate_world(RoadConfig(), s) for s in range(5)]
    for i in range(5):
        for j in range(i + 1, 5):
            assert not np.array_equal(worlds[i].frames, worlds[j].frames)


@given(configs, seeds)
def test_matches_the_stepwise_simulation(cfg, seed):
    world = generate_world(cfg, seed)
    frames, goal = simulate_world(cfg, seed)
    np.testing.assert_array_equal(world.frames, frames)
    np.testing.assert_allclose(world.goal, goal, atol=1e-9)


@given(configs, seeds)
def test_obstacles_only_on_lanes_with_their_class_value(cfg, seed):
    world = generate_world(cfg, seed)
    obstacles = obstacle_mask(world.frames)
    off_lane = np.setdiff1d(np.arange(cfg.height), lane_rows(cfg.height))
    assert not obstacles[:, off_lane].any()
    values = np.array(cfg.obstacle_values)
    for row, cls in zip(world.layout.rows, world.layout.cls, strict=True):
        seen = np.unique(world.frames[:, row][obstacles[:, row]])
        assert set(seen) <= {values[cls]}


@given(configs, seeds)
def test_each_lane_flows_one_way(cfg, seed):
    """Every obstacle pixel of frame t+1 is either in its lane's entry zone or a pixel of frame t shifted
    0…3 columns downstream (speeds are at most 2.3 px/step)."""
    world = generate_world(cfg, seed)
    obstacles = obstacle_mask(world.frames)
    W = cfg.width
    for row, cls, d in zip(world.layout.rows, world.layout.cls, world.layout.direction, strict=True):
        length = cfg.classes[cls].length
        entry = np.zeros(W, bool)
        if d > 0:
            entry[:length] = True
        else:
            entry[W - 1 - length : W - 1] = True
        lane = obstacles[:, row]  # (T, W)
        previous = lane[:-1]
        reachable = np.zeros_like(previous)
        for shift in range(4):
            if d > 0:
                reachable[:, shift:] |= previous[:, : W - shift]
            else:
                reachable[:, : W - shift] |= previous[:, shift:]
        assert not (lane[1:] & ~reachable & ~entry).any()


@given(configs, seeds)
def test_goal_is_a_full_block_inside_the_grid_unless_covered(cfg, seed):
    world = generate_world(cfg, seed)
    gy, gx = world.goal_px.T
    assert (gy >= 0).all() and (gy + 1 < cfg.height).all() and (gx >= 0).all() and (gx + 1 < cfg.width).all()
    t = np.arange(len(world.frames))
    block = world.frames[t[:, None, None], gy[:, None, None] + np.arange(2)[:, None], gx[:, None, None] + np.arange(2)]
    covered = obstacle_mask(block)
    assert ((block == GOAL_VALUE) | covered).all()
    assert (world.frames == GOAL_VALUE).sum() == (block == GOAL_VALUE).sum()  # no goal pixels anywhere else


@given(configs, seeds)
def test_goal_moves_at_its_speed_and_reflects_off_walls(cfg, seed):
    world = generate_world(cfg, seed)
    span = np.array([cfg.height - 2, cfg.width - 2])
    step = np.diff(world.goal, axis=0)
    assert (world.goal >= 0).all() and (world.goal <= span).all()
    # Away from the walls the goal moves in a straight line at goal_speed.
    margin = cfg.goal_speed + 1e-9
    free = ((world.goal[:-1] > margin) & (world.goal[:-1] < span - margin)).all(axis=1)
    free &= ((world.goal[1:] > margin) & (world.goal[1:] < span - margin)).all(axis=1)
    np.testing.assert_allclose(np.linalg.norm(step[free], axis=1), cfg.goal_speed, rtol=1e-9)
    # A velocity component only flips next to the wall it bounced off (mirror reflection).
    flips = np.sign(step[1:]) != np.sign(step[:-1])
    near_wall = (world.goal[1:-1] <= margin) | (world.goal[1:-1] >= span - margin)
    assert not (flips & ~near_wall).any()
    # Headings are 1° + 45°·k.
    first = step[0] if free[0] else step[free.argmax()] if free.any() else None
    if first is not None:
        heading = np.degrees(np.arctan2(*first)) % 45  # reflections keep the angle to the axes
        assert min(abs(heading - 1), abs(heading - 44)) < 1e-6


def test_goal_reflection_golden():
    """Crossing the bottom wall, the straight-line position y − |vy| is mirrored: y' = |vy| − y."""
    cfg = RoadConfig()
    checked = 0
    for seed in range(100):
        y = generate_world(cfg, seed).goal[:, 0]
        dy = np.diff(y)
        vy = np.abs(dy).max()  # reached on every step away from the walls
        for i in np.nonzero(np.isclose(dy[:-1], -vy) & (y[1:-1] - vy < 0))[0] + 1:
            assert y[i + 1] == pytest.approx(vy - y[i], abs=1e-9)
            checked += 1
    assert checked > 5


def test_lanes_are_dealt_round_robin_to_classes():
    world = generate_world(RoadConfig(), 0)
    counts = np.bincount(world.layout.cls, minlength=5)
    assert list(counts) == [9, 9, 8, 8, 8]  # tesla, wagon, sport, truck, sedan
    directions = np.concatenate([generate_world(RoadConfig(), s).layout.direction for s in range(50)])
    assert set(np.unique(directions)) == {-1, 1}
    assert abs((directions > 0).mean() - 0.5) < 0.05


def test_level_zero_has_no_obstacles():
    world = generate_world(RoadConfig(level=0), 3)
    assert not obstacle_mask(world.frames).any()


def test_per_lane_spawn_rate_follows_the_poisson_rule():
    """At level 6 each lane spawns with P(Poisson(3.5·len) < 6) per step (sedan 0.0504, sport 0.0055)."""
    cfg = RoadConfig(agent_speed=0.5)
    spawns = np.zeros(5)
    trials = np.zeros(5)
    for seed in range(300):
        world = generate_world(cfg, seed)
        n_steps = cfg.width + len(world.frames) - 1
        trials += n_steps * np.bincount(world.layout.cls, minlength=5)
        spawns += np.bincount(world.layout.cls[world.traffic.lane], minlength=5)
    rate = spawns / trials
    for cls, c in enumerate(cfg.classes):
        # An independent draw of the rule itself, not the closed form the generator uses.
        k = np.random.default_rng(cls).poisson(3.5 * c.length, size=2_000_000)
        p = (k < cfg.level).mean()
        assert p == pytest.approx(spawn_probability(c.length, cfg.level), abs=5 * np.sqrt(p * (1 - p) / 2e6) + 1e-6)
        sigma = np.sqrt(p * (1 - p) / trials[cls])
        assert abs(rate[cls] - p) < 5 * sigma + 1e-6, (c.name, rate[cls], p)
    per_step = spawns.sum() / (trials.sum() / len(lane_rows(48)))
    assert per_step == pytest.approx(0.45, abs=0.03)


def test_speeds_are_drawn_from_the_class_choices():
    cfg = RoadConfig(agent_speed=0.5)
    world = generate_world(cfg, 11)
    table = np.array([c.speeds for c in cfg.classes])
    cls = world.layout.cls[world.traffic.lane]
    speed = np.abs(world.traffic.velocity)
    assert np.isclose(speed[:, None], table[cls]).any(axis=1).all()
    assert (np.sign(world.traffic.velocity) == world.layout.direction[world.traffic.lane]).all()


def test_occupancy_golden_statistics_and_warm_up():
    """About 2% of lane pixels are occupied at level 6, already at frame 0 thanks to the W-step warm-up."""
    cfg = RoadConfig(agent_speed=0.5)
    lanes = lane_rows(48)
    overall, first = [], []
    for seed in range(100):
        obstacles = obstacle_mask(generate_world(cfg, seed).frames)[:, lanes]
        overall.append(obstacles.mean())
        first.append(obstacles[0].mean())
    assert np.mean(overall) == pytest.approx(0.0207, abs=0.002)
    assert np.mean(first) == pytest.approx(np.mean(overall), abs=0.003)


@pytest.mark.parametrize("seed", [-1, 1.5, "3"])
def test_bad_seed_is_rejected(seed):
    with pytest.raises(ValueError, match=r"^generate_world: seed=.* is invalid \("):
        generate_world(RoadConfig(), seed)
