"""Atari Freeway as a world that does not depend on the agent: the NOOP shadow's screen is the real game's but for
the chickens and the score, at every step of random play; its lane frames are the same bytes for the same episode
and a later NOOP start is the same traffic further on; the game is the one the public scoreboard plays (2,048
steps, always-UP scores 21); and the chicken's rule, which the planner simulates, predicts the emulator's chicken
from the world's frames."""

from __future__ import annotations

import builtins

import numpy as np
import pytest

from dynplan.config import ConfigError
from dynplan.extras import MissingExtra
from dynplan.worlds.freeway import game as freeway
from dynplan.worlds.freeway.game import Chicken, FreewayEpisode, FreewayGame, chicken_step

pytest.importorskip("ale_py")  # the `atari` extra, in `dev`: installed wherever the suite runs


def _outside_the_chickens_and_score(y: int) -> np.ndarray:
    """Screen pixels outside the real chicken's box at height `y`, the idle chicken's and the score's (each grown by
    one pixel: the sprite's edge rows)."""
    keep = np.ones((210, 160), bool)
    keep[max(193 - y - 1, 0) : 200 - y + 1, freeway.CHICKEN_COLUMNS] = False
    keep[freeway.IDLE_CHICKEN_ROWS, freeway.CHICKEN_COLUMNS] = False
    keep[freeway.SCORE_BOX] = False
    return keep


def test_the_shadow_is_the_real_game_without_its_chicken():
    game, rng = FreewayGame(FreewayEpisode(mode=0, noop_start=3)), np.random.default_rng(0)
    differing, crossings = 0, 0
    for _ in range(600):
        step = game.step(int(rng.choice(3, p=[0.2, 0.6, 0.2])))
        real, shadow = game.real.getScreen(), game.shadow.getScreen()
        differing += bool((real != shadow)[_outside_the_chickens_and_score(step.chicken.y)].any())
        crossings += step.reward
        np.testing.assert_array_equal(step.frame, shadow[freeway.LANE_ROWS, freeway.LANE_COLUMNS][::-1])
    assert differing == 0
    assert crossings >= 1  # among the steps compared, the chicken's crossings and the waits after them


def test_an_episodes_frames_are_the_same_bytes_and_a_later_start_is_the_same_traffic_further_on():
    def frames(noop_start: int, n: int = 40) -> list[np.ndarray]:
        game = FreewayGame(FreewayEpisode(noop_start=noop_start))
        return [game.step(0).frame for _ in range(n)]

    first, again, later = frames(7), frames(7), frames(8)
    assert all(a.tobytes() == b.tobytes() for a, b in zip(first, again, strict=True))
    assert all(a.tobytes() == b.tobytes() for a, b in zip(first[1:], later[:-1], strict=True))
    assert first[0].shape == (154, 152) and first[0].dtype == np.uint8
    assert len(np.unique(np.concatenate([f.ravel() for f in first]))) > 4  # road, lane marks and cars


@pytest.mark.slow
def test_the_game_lasts_2048_steps_and_always_up_scores_21():
    game, steps, score = FreewayGame(), 0, 0.0
    while True:
        step = game.step(1)
        steps, score = steps + 1, score + step.reward
        if step.done:
            break
    assert (steps, score) == (freeway.GAME_STEPS, 21.0)


def test_the_chickens_timer_is_a_knock_or_a_wait():
    game, rng, seen = FreewayGame(), np.random.default_rng(1), set()
    for _ in range(400):
        before = game.chicken.y
        step = game.step(int(rng.choice(3, p=[0.1, 0.8, 0.1])))
        if step.reward:
            assert step.chicken.y == 6 and step.chicken.timer >= freeway.WAIT_END  # back on the sidewalk, waiting
            seen.add("wait")
        elif step.chicken.knocked and step.chicken.y < before:
            seen.add("knock")  # a car hit it: pushed down whatever it was told
    assert seen == {"wait", "knock"}


def test_bad_episodes_and_actions_are_refused_in_one_line():
    with pytest.raises(ConfigError, match=r"mode=8 is invalid .*valid range \[0, 7\]"):
        FreewayEpisode(mode=8)
    with pytest.raises(ConfigError, match=r"noop_start=31 is invalid .*valid range \[0, 30\]"):
        FreewayEpisode(noop_start=31)
    with pytest.raises(ValueError, match=r"action=3 is invalid \(valid range \[0, 2\]\)"):
        FreewayGame().step(3)


def test_without_the_extra_the_game_says_how_to_install_it(monkeypatch):
    real_import = builtins.__import__

    def no_ale(name, *args, **kwargs):
        if name.split(".")[0] == "ale_py":
            raise ImportError(name)
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_ale)
    with pytest.raises(MissingExtra, match=r"Atari Freeway needs the ale_py package: pip install -e '\.\[atari\]'"):
        FreewayGame()


def _rule_exact(episode: FreewayEpisode, p: list[float], seed: int, steps: int) -> tuple[float, float]:
    """The shares of steps on which `chicken_step`, from the chicken's RAM state before the step and the world's
    frames before and after it, gives the emulator's height, and its whole state (height, timer) and reward."""
    game, rng, heights, states = FreewayGame(episode), np.random.default_rng(seed), 0, 0
    before = game.world_frame()
    for _ in range(steps):
        now, action = game.chicken, int(rng.choice(3, p=p))
        step = game.step(action)
        predicted = chicken_step(now, action, before, step.frame)
        heights += predicted[0].y == step.chicken.y
        states += predicted == (step.chicken, step.reward)
        before = step.frame
    return heights / steps, states / steps


@pytest.mark.parametrize("mode", [0, 1])
def test_the_chickens_rule_predicts_the_emulator(mode):
    """Mode 0 and mode 1 (up to 3 cars a lane, faster): the height exact on ≥ 99 % of the steps of random play and
    of a mostly-UP play's (more crossings and hits); the whole state and reward on ≥ 98 % and ≥ 95 %."""
    random_play = _rule_exact(FreewayEpisode(mode=mode, noop_start=11), [1 / 3, 1 / 3, 1 / 3], seed=5, steps=1500)
    mostly_up = _rule_exact(FreewayEpisode(mode=mode, noop_start=3), [0.1, 0.8, 0.1], seed=6, steps=1500)
    assert random_play[0] >= 0.99 and mostly_up[0] >= 0.99, (random_play, mostly_up)
    assert random_play[1] >= 0.98 and mostly_up[1] >= 0.95, (random_play, mostly_up)


def test_the_steps_frames_follow_each_lanes_cars():
    """`lane_shifts` finds each lane's move between two world frames (mode 1: up to 8 columns a step), and
    `step_frames` draws the cars part of the way: in the emulator's own frames within the step, every lane's cars
    stand within a column of where it draws them, and exactly there in most."""
    from dynplan.worlds.freeway.game import emulator, lane_frame, lane_shifts, step_frames

    ale, frames = emulator(1), []
    for _ in range(4 * 60):
        frames.append(lane_frame(ale.getScreen()))
        ale.act(0)
    frames = np.stack(frames)
    offsets = []
    for t in range(40, 59):
        before, after, within = frames[4 * t], frames[4 * t + 4], frames[4 * t : 4 * t + 4]
        moves = lane_shifts(before, after)
        assert np.abs(moves).max() <= freeway.MAX_SHIFT and np.abs(moves).max() >= 4
        drawn = step_frames(before, after)
        offsets += [lane_shifts(drawn[k], within[k]) for k in range(1, 4)]
    offsets = np.abs(np.concatenate(offsets))
    assert offsets.max() <= 1 and (offsets == 0).mean() > 0.7, np.bincount(offsets)


def test_the_sprite_table_is_the_chickens():
    """The measured sprites (`python -m lab.freeway_sprites`): one per height, a chicken-sized shape
    in the box's middle rows; a car pixel on the sprite hits, beside it does not."""
    sprites = np.load(freeway.SPRITES)
    assert sprites.shape == (freeway.TOP_Y + 1, 8, 8) and sprites.dtype == bool
    assert all(12 <= s.sum() <= 40 for s in sprites[20:167])
    road = np.full((154, 152), 6, np.uint8)
    r, c = np.argwhere(sprites[60])[0]
    car = road.copy()
    car[60 + freeway.SPRITE_ROWS[0] + r, freeway.SPRITE_COLUMNS.start + c] = 136
    assert freeway.sprite_hit(car, 60) and not freeway.sprite_hit(road, 60)
    assert not freeway.sprite_hit(car, 90)


def test_the_rule_on_an_empty_road():
    road = np.full((154, 152), 6, np.uint8)
    assert chicken_step(Chicken(6), 1, road, road) == (Chicken(10), 0.0)  # 4 pixels a step
    assert chicken_step(Chicken(8), 2, road, road) == (Chicken(6), 0.0)  # not below the sidewalk
    assert chicken_step(Chicken(174), 1, road, road) == (Chicken(6, freeway.WAIT_TIMER), 1.0)  # a crossing
    assert chicken_step(Chicken(6, 132), 1, road, road) == (Chicken(6, 130), 0.0)  # waiting: the action is ignored
    assert chicken_step(Chicken(6, 130), 1, road, road) == (Chicken(6, 0), 0.0)  # the wait ends with the step
    stunned = chicken_step(Chicken(50, 70), 1, road, road)[0]
    assert stunned == Chicken(50, 68)  # stunned: the action is ignored
    car = road.copy()
    car[58 + freeway.SPRITE_ROWS[0] : 58 + freeway.SPRITE_ROWS[1], freeway.SPRITE_COLUMNS] = 136  # over the chicken
    hit = chicken_step(Chicken(58), 1, car, car)[0]
    assert hit == Chicken(56, freeway.HIT_TIMER - 2)  # hit on the step's first frame: sliding back
