"""`dynplan/Road-v0`: the Gymnasium contract and the agent's rules on hand-built worlds."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import dynplan
from dynplan.env import FIRST_DECISION_FRAME, GOAL_VALUE, RoadConfig, RoadEnv, World, generate_world
from dynplan.env.colors import palette

# Action indices (headings −180°, −135°, …, 135°).
LEFT, DOWN, RIGHT, UP, UP_RIGHT = 0, 2, 4, 6, 5


def blank_world(cfg: RoadConfig, start=(0.0, 10.0), goal=(30.0, 30.0)) -> World:
    """An empty world (no traffic) whose goal sits still at `goal`; obstacles are painted in by each test."""
    T = cfg.max_steps
    frames = np.zeros((T, cfg.height, cfg.width), np.uint8)
    gy, gx = int(goal[0]), int(goal[1])
    frames[:, gy : gy + 2, gx : gx + 2] = GOAL_VALUE
    return World(cfg, 0, frames, np.tile(np.asarray(goal, float), (T, 1)), np.asarray(start, float))


def play(world: World, actions, **config):
    env = RoadEnv(config=world.config, **config)
    obs, info = env.reset(options={"world": world})
    results = [env.step(a) for a in actions]
    return env, obs, info, results


def test_registered_and_passes_the_gymnasium_checker():
    env = gym.make("dynplan/Road-v0", agent_speed=1.0, level=6)
    assert isinstance(env.unwrapped, RoadEnv)
    check_env(env.unwrapped)
    assert env.action_space == gym.spaces.Discrete(8)
    assert env.observation_space["frame"].shape == (48, 48)
    assert env.observation_space["frame"].dtype == np.uint8
    assert env.observation_space["agent"].shape == (2,)


def test_reset_with_a_seed_is_reproducible_and_matches_generate_world():
    env = gym.make("dynplan/Road-v0", agent_speed=0.5)
    obs1, _ = env.reset(seed=42)
    frames1 = env.unwrapped.world_frames.copy()
    obs2, _ = env.reset(seed=42)
    np.testing.assert_array_equal(env.unwrapped.world_frames, frames1)
    np.testing.assert_array_equal(obs1["agent"], obs2["agent"])
    assert frames1.shape == (407, 48, 48) and frames1.dtype == np.uint8
    np.testing.assert_array_equal(frames1, generate_world(RoadConfig(agent_speed=0.5), 42).frames)
    env.reset(seed=43)
    assert not np.array_equal(env.unwrapped.world_frames, frames1)
    # Unseeded resets continue a reproducible sequence.
    env.reset(seed=1)
    a = [env.reset()[0]["agent"] for _ in range(3)]
    env.reset(seed=1)
    b = [env.reset()[0]["agent"] for _ in range(3)]
    np.testing.assert_array_equal(a, b)


def test_start_state_and_first_decision_at_frame_4():
    env = RoadEnv()
    for seed in range(40):
        obs, info = env.reset(seed=seed)
        y, x = obs["agent"]
        assert y in (0.0, 46.0) and 6 <= x < 42 and x == int(x)
        assert info["t"] == FIRST_DECISION_FRAME
        np.testing.assert_array_equal(obs["frame"], env.world_frames[FIRST_DECISION_FRAME])
        obs, *_ = env.step(RIGHT)
        np.testing.assert_array_equal(obs["frame"], env.world_frames[FIRST_DECISION_FRAME + 1])


def test_action_headings():
    world = blank_world(RoadConfig(), start=(20.0, 20.0))
    env = RoadEnv()
    env.reset(options={"world": world})
    moves = {LEFT: (0, -1), DOWN: (-1, 0), RIGHT: (0, 1), UP: (1, 0), UP_RIGHT: (np.sqrt(0.5), np.sqrt(0.5))}
    for action, (dy, dx) in moves.items():
        before = env.position.copy()
        env.step(action)
        np.testing.assert_allclose(env.position - before, (dy, dx), atol=1e-12)


def test_death_off_the_grid():
    world = blank_world(RoadConfig(), start=(0.0, 10.0))
    env, _, _, [(obs, reward, terminated, truncated, info)] = play(world, [DOWN])
    assert (reward, terminated, truncated, info["outcome"]) == (-20.0, True, False, "death")
    assert obs["agent"][0] == -1.0
    with pytest.raises(RuntimeError, match="episode has ended"):
        env.step(UP)
    with pytest.raises(RuntimeError, match="call reset"):
        RoadEnv().step(UP)


def test_rounding_halves_up_keeps_the_agent_alive_at_minus_half():
    world = blank_world(RoadConfig(agent_speed=0.5), start=(0.0, 10.0))
    _env, *_, results = play(world, [DOWN, DOWN])
    assert results[0][4]["outcome"] == "running"  # y = −0.5 rounds to row 0
    assert results[1][4]["outcome"] == "death"  # y = −1.0


def test_death_on_an_obstacle_judged_on_the_next_frame():
    cfg = RoadConfig()
    world = blank_world(cfg, start=(0.0, 10.0))
    world.frames[FIRST_DECISION_FRAME, 1, 10] = 144  # present now, gone when the agent arrives: safe
    _, _, _, [(_, reward, terminated, _, info)] = play(world, [UP])
    assert (reward, terminated) == (0.0, False)
    world = blank_world(cfg, start=(0.0, 10.0))
    world.frames[FIRST_DECISION_FRAME + 1, 1, 10] = 45  # arrives with the agent: death
    _, _, _, [(_, reward, terminated, _, info)] = play(world, [UP])
    assert (reward, terminated, info["outcome"]) == (-20.0, True, "death")


def test_goal_capture_and_a_covered_goal_pixel_kills():
    cfg = RoadConfig()
    world = blank_world(cfg, start=(29.0, 30.0), goal=(30.0, 30.0))
    _, _, _, [(_, reward, terminated, truncated, info)] = play(world, [UP])
    assert (reward, terminated, truncated, info["outcome"]) == (20.0, True, False, "goal")
    world = blank_world(cfg, start=(29.0, 30.0), goal=(30.0, 30.0))
    world.frames[FIRST_DECISION_FRAME + 1, 30, 30] = 100  # an obstacle drives over that goal pixel
    _, _, _, [(_, reward, _, _, info)] = play(world, [UP])
    assert (reward, info["outcome"]) == (-20.0, "death")


def test_timeout_when_the_frame_index_reaches_T_minus_1():
    cfg = RoadConfig()
    world = blank_world(cfg, start=(10.0, 20.0))
    env = RoadEnv()
    env.reset(options={"world": world})
    steps = 0
    while True:
        _, reward, terminated, truncated, info = env.step([LEFT, RIGHT][steps % 2])
        steps += 1
        if terminated or truncated:
            break
    assert (truncated, terminated, reward, info["outcome"]) == (True, False, 0.0, "timeout")
    assert info["t"] == cfg.max_steps - 1 == 202
    assert steps == cfg.max_steps - 1 - FIRST_DECISION_FRAME


def test_reset_rejects_bad_options_and_short_worlds():
    env = RoadEnv()
    with pytest.raises(ValueError, match="unknown reset option"):
        env.reset(options={"wrold": None})
    short = generate_world(RoadConfig(), 0, n_frames=100)
    with pytest.raises(ValueError, match="at least"):
        env.reset(options={"world": short})
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"action must be an integer in \[0, 7\]"):
        env.step(9)


def test_vector_env_runs_and_autoresets():
    envs = gym.make_vec("dynplan/Road-v0", num_envs=3, vectorization_mode="sync", agent_speed=1.0)
    obs, _ = envs.reset(seed=[1, 2, 3])
    assert obs["frame"].shape == (3, 48, 48) and obs["agent"].shape == (3, 2)
    ended = np.zeros(3, bool)
    for _ in range(250):  # longer than an episode, so every sub-env ends and autoresets at least once
        obs, _reward, terminated, truncated, _ = envs.step(envs.action_space.sample())
        ended |= terminated | truncated
    assert ended.all()
    envs.close()


def test_render_uses_the_papers_colours():
    env = gym.make("dynplan/Road-v0", render_mode="rgb_array")
    obs, _ = env.reset(seed=5)
    image = env.render()
    assert image.shape == (48, 48, 3) and image.dtype == np.uint8
    colours = palette()
    y, x = np.floor(obs["agent"] + 0.5).astype(int)
    assert tuple(image[47 - y, x]) == tuple(colours[200])  # row 0 is drawn at the bottom
    violet, yellow = colours[0], colours[GOAL_VALUE]
    assert violet[2] > violet[1] and yellow[0] > 200 and yellow[1] > 200 and yellow[2] < 60
    assert (colours[[45, 85, 100, 130, 144], 2] > colours[[45, 85, 100, 130, 144], 0]).all()  # blue/cyan
    assert dynplan.RoadEnv is RoadEnv
