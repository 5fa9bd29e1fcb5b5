"""Planning Freeway's chicken and evaluating it on the real game: the exact search crosses an empty road, waits for
a car rather than meet it, and counts crossings within its horizon; the oracle, planning with the true future, scores
above every world-model agent of the public scoreboard without a knock; an evaluation writes one result file per
episode and resumes from them."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest
from PIL import Image

from dynplan.config import ConfigError
from dynplan.evaluation.store import ROAD_RUNS, Run, StoreError
from dynplan.worlds.freeway import evaluation
from dynplan.worlds.freeway.evaluation import FreewayPlan, evaluate_episodes, read_run, summarise
from dynplan.worlds.freeway.game import BOTTOM_Y, ROAD_VALUES, Chicken, FreewayEpisode, chicken_step
from dynplan.worlds.freeway.replay import GIF_STEPS
from dynplan.worlds.freeway.results import RUNS, SETTINGS, decode_actions, encode_actions, replay_check, settings
from dynplan.worlds.freeway.search import ChickenSearch, plan_chicken

pytest.importorskip("ale_py")  # the `atari` extra, in `dev`: installed wherever the suite runs

ROAD = np.full((9, 154, 152), ROAD_VALUES[0], np.uint8)


def test_on_an_empty_road_the_chicken_goes_up_and_counts_its_crossings():
    decision = plan_chicken(Chicken(BOTTOM_Y), ROAD)
    assert decision.action == 1 and list(decision.crossings) == [0, 0, 0]
    assert decision.height[1] == BOTTOM_Y + 32  # 8 steps of 4 pixels
    assert decision.height[1] > decision.height[0] == decision.height[2]  # not below the sidewalk
    near_the_top = plan_chicken(Chicken(170), ROAD, ChickenSearch(horizon=3))
    assert near_the_top.action == 1 and near_the_top.crossings[1] == 1 and near_the_top.search_ms >= 0
    with pytest.raises(ValueError, match="needs the frame now and one more"):
        plan_chicken(Chicken(BOTTOM_Y), ROAD[:1])
    with pytest.raises(ConfigError, match="horizon=0 is invalid"):
        ChickenSearch(horizon=0)


def test_the_chicken_waits_for_a_car_rather_than_meet_it():
    frames = np.full((40, 154, 152), ROAD_VALUES[0], np.uint8)
    frames[1:4, 50:58, 30:50] = 136  # a car just above a chicken at height 60 for three steps
    chicken, actions = Chicken(60), []
    for t in range(8):
        actions.append(plan_chicken(chicken, frames[t : t + 7], ChickenSearch(horizon=6)).action)
        chicken, _ = chicken_step(chicken, actions[-1], frames[t], frames[t + 1])
        assert not chicken.knocked, (t, actions)
    assert actions[0] == 0 and chicken.y > 64  # it waits below the car (not lower), then goes up past it


def test_an_evaluations_episodes_are_drawn_from_its_seed():
    plan = FreewayPlan(mode=1, episodes=20, seed=3)
    starts = [e.noop_start for e in plan.episode_list()]
    assert starts == [e.noop_start for e in FreewayPlan(mode=1, episodes=20, seed=3).episode_list()]
    assert all(0 <= n <= 30 for n in starts) and len(set(starts)) > 5
    assert starts != [e.noop_start for e in FreewayPlan(mode=1, episodes=20, seed=4).episode_list()]
    with pytest.raises(ConfigError, match=r"mode=8 is invalid.*valid range \[0, 7\]"):
        FreewayPlan(mode=8)


def _run(root, name="run"):
    run = Run(root, name, RUNS)
    run.start("candidate", SETTINGS, {}, "tests")
    return run


def test_an_evaluation_resumes_from_its_run_and_its_rows_replay(tmp_path, monkeypatch):
    plan, search, run = FreewayPlan(mode=0, episodes=2, seed=0), ChickenSearch(horizon=4), _run(tmp_path)
    played = evaluate_episodes(run, "up", plan, [1], search)[0]
    assert played["episode"] == 1 and played["noop_start"] == plan.episode_list()[1].noop_start
    assert played["score"] >= 20 and played["actions"] == f"U{played['steps']}" and replay_check(played) is None
    other_seed = evaluate_episodes(run, "up", FreewayPlan(mode=0, episodes=2, seed=5), [1], search)[0]
    assert other_seed["noop_start"] == FreewayPlan(mode=0, episodes=2, seed=5).episode_list()[1].noop_start
    monkeypatch.setattr(evaluation, "play_episodes", lambda *a, **k: pytest.fail("an episode the run holds is played"))
    assert evaluate_episodes(run, "up", plan, [1], search)[0] == played
    assert read_run(tmp_path, "run") == [played, other_seed]
    assert "score 0, 0 knocks" in replay_check({**played, "actions": f"N{played['steps']}"})
    assert "not ending on the last" in replay_check({**played, "actions": f"U{played['steps'] - 1}"})
    assert decode_actions(encode_actions([1, 1, 0, 2, 2, 2, 1])) == [1, 1, 0, 2, 2, 2, 1]
    assert encode_actions("1102221") == "U2N1D3U1"


def test_a_sticky_run_replays_with_its_own_settings(tmp_path):
    """With sticky actions the game repeats frames of the last action, drawn from each episode's seed: a row
    replays to its score, knocks and steps with its run's settings, and the deterministic game would not."""
    run = Run(tmp_path, "sticky", RUNS)
    run.start("evaluation", settings(0.25), {}, "tests")
    plan = FreewayPlan(mode=0, episodes=2, sticky=0.25)
    rows = evaluate_episodes(run, "random", plan, [0, 1], ChickenSearch(horizon=2))
    assert all(replay_check(row, settings(0.25)) is None for row in rows)
    assert replay_check(rows[1], SETTINGS) == (
        "its actions replay to score 0, 17 knocks, 2029 steps; the row says 0, 16, 2029"
    )
    with pytest.raises(StoreError, match="has settings"):
        run.start("evaluation", SETTINGS, {}, "tests")


def test_a_run_refuses_a_row_it_cannot_hold(tmp_path):
    run, plan, search = _run(tmp_path), FreewayPlan(mode=0, episodes=1), ChickenSearch(horizon=2)
    row = evaluate_episodes(run, "up", plan, [0], search)[0]
    for bad, why in (({"score": 1e9}, "score"), ({"score": "abc"}, "score"), ({"mode": 9}, "mode"),
                     ({"actions": "13"}, "actions"), ({"actions": "U3"}, "3 actions"), ({"extra": 1}, "extra"),
                     ({"steps": True}, "steps")):  # fmt: skip
        with pytest.raises(StoreError, match=why):
            run.append({**row, "episode": 5, **bad})
    (run.episodes_path).write_text(run.episodes_path.read_text() + json.dumps({**row, "score": 1e9}) + "\n")
    with pytest.raises(StoreError, match=r"episodes.jsonl:2: field 'score' = 1000000000.0 is out of range"):
        read_run(tmp_path, "run")
    road = Run(tmp_path, "run")  # a road run of the same name: refused, naming the world
    with pytest.raises(StoreError, match="holds freeway-v1 episodes"):
        Run(tmp_path, "run", ROAD_RUNS).manifest()
    assert road.kind is RUNS


def test_a_summary_gives_each_techniques_mean_score_and_knocks():
    def row(technique, score, knocks, ms=None):
        return {"technique": technique, "mode": 0, "horizon": 8, "score": score, "knocks": knocks, "decision_ms": ms}

    rows = [row("up", 21, 40), row("oracle", 34, 0, 9.0), row("up", 23, 44), row("oracle", 33, 1, 11.0)]
    summary = summarise(rows)
    assert [s["technique"] for s in summary] == ["oracle", "up"]
    assert summary[0] | {} == {"mode": 0, "technique": "oracle", "horizon": 8, "episodes": 2, "score": 33.5,
                               "std": 0.5, "knocks": 0.5, "decision_ms": 10.0}  # fmt: skip
    assert summary[1]["score"] == 22.0 and summary[1]["decision_ms"] is None
    json.dumps(summary)


@pytest.mark.slow
def test_the_oracle_plays_the_real_game_above_the_scoreboard():
    """With the true future the search scores ≥ 33.5 without a knock (STORM's 33.5 tops the world-model agents)."""
    played = evaluation.play_episode("oracle", FreewayEpisode(mode=0, noop_start=7), ChickenSearch(horizon=8))
    assert played.score >= 33.5 and played.knocks == 0 and played.steps == 2048 - 7


def test_merging_coinciding_plans_changes_no_decision():
    """The search merges action sequences that reach the same state after the same first action; the naive search
    over all 3^k sequences (`dynplan.worlds.freeway.bench`) picks the same action along a stretch of a real game."""
    from dynplan.worlds.freeway.bench import naive_action
    from dynplan.worlds.freeway.game import FreewayGame, record_mode

    future, game = record_mode(1, 260).frames, FreewayGame(FreewayEpisode(mode=1))
    for t in range(0, 250):
        decision = plan_chicken(game.chicken, future[t : t + 6], ChickenSearch(horizon=5))
        if t % 10 == 0:
            assert decision.action == naive_action(game.chicken, future[t : t + 6], 5), t
        game.step(decision.action)


def test_a_replay_log_holds_the_modes_lanes_and_the_chickens_track(tmp_path, prefect_api):
    """`flows.replay --world freeway` plays the real game from the NOOP start and writes the mode's recording with
    the chicken's track (entering at frame n), its steps' rewards summing to the game's score, and the lanes the
    planner searched; a log that is no whole Freeway mode's recording is refused in one line."""
    from dynplan.data.collect import record_episode
    from dynplan.logs.reader import read_episode_log
    from flows.replay import main

    logs = tmp_path / "logs"
    log = record_episode(logs, 0, None, None, "freeway").path
    result = main([log, "--world", "freeway", "--noop-start", "4", "--technique", "zero", "--horizon", "2",
                   "--out", str(tmp_path / "zero.mcap"), "--gif", str(tmp_path / "zero.gif")])  # fmt: skip
    replay = read_episode_log(tmp_path / "zero.mcap")
    assert replay.metadata["kind"] == "agent" and replay.n_frames == 2049 and replay.entry.name == "freeway"
    np.testing.assert_array_equal(replay.agent.t, np.arange(4, 2049))
    assert replay.agent.reward.sum() == result["score"] >= 20 and replay.agent.outcome[-1] == "timeout"
    assert sorted(replay.imagined)[0] == 4 and replay.imagined[4].shape == (2, 154, 152)
    with Image.open(tmp_path / "zero.gif") as gif:  # the first steps: now | true | searched | error, k = 2 on
        assert gif.n_frames == GIF_STEPS and gif.size == (4 * 152 + 3, 154)
    short = record_episode(tmp_path / "short", 1, None, 100, "freeway").path
    for argv in ([short, "--world", "freeway"], [log, "--world", "freeway", "--technique", "up", "--gif", "up.gif"]):
        with pytest.raises(SystemExit) as exit_:
            main(argv)
        assert exit_.value.code == 2


def test_the_lab_predictor_moves_each_lane_at_its_mean_speed():
    """`lab.freeway_predictors.shifted`: a car that moved 5 columns over 4 steps is imagined 1.25
    columns a step further on, rounded, and an empty lane stays empty."""
    from lab.freeway_predictors import shifted

    observed = np.full((5, 154, 152), ROAD_VALUES[0], np.uint8)
    for step, column in enumerate((40, 41, 42, 44, 45)):
        observed[step, 17:25, column : column + 8] = 136  # lane 1's car
    imagined = shifted(observed, 4)
    starts = [int(np.flatnonzero(frame[20] == 136)[0]) for frame in imagined]
    assert starts == [46, 48, 49, 50]  # 45 + 1.25, 2.5, 3.75, 5 rounded half up
    assert (imagined[:, 0:16] == ROAD_VALUES[0]).all()


def test_the_oracle_searches_the_true_lanes_of_each_step():
    episode = FreewayEpisode(mode=0, noop_start=3)
    turns = list(itertools.islice(evaluation.play_turns("oracle", episode, ChickenSearch(horizon=3)), 24))
    recording = evaluation.record_mode(0).frames
    for t in (0, 17, 23):  # past the frames a learned agent keeps of what it observed
        np.testing.assert_array_equal(turns[t].frames, recording[3 + t : 3 + t + 4])


def test_the_extrapolator_moves_each_lane_on_at_its_recent_speed():
    """A car of lane 3 moving 2 columns a step and one of lane 7 moving 3 back: the extrapolated frames are the
    true ones; a technique searching them (`extrapolate`) sees the lanes now, then those."""
    from dynplan.worlds.freeway.evaluation import searched_frames
    from dynplan.worlds.freeway.game import extrapolated

    def frame(t: int) -> np.ndarray:
        lanes = np.full((154, 152), ROAD_VALUES[0], np.uint8)
        lanes[3 * 16 + 1 : 3 * 16 + 9, (40 + 2 * t + np.arange(8)) % 152] = 136
        lanes[7 * 16 + 1 : 7 * 16 + 9, (100 - 3 * t + np.arange(8)) % 152] = 74
        return lanes

    truth = np.stack([frame(t) for t in range(9)])
    np.testing.assert_array_equal(extrapolated(truth[:5], 4), truth[5:])
    seen = searched_frames(list(truth[:5]), ChickenSearch(horizon=4), "extrapolate")
    np.testing.assert_array_equal(seen, truth[4:])
    np.testing.assert_array_equal(
        searched_frames([truth[0]], ChickenSearch(horizon=2), "extrapolate"), truth[[0, 0, 0]]
    )


def test_episodes_in_lockstep_decide_as_each_alone():
    """A lockstep batch makes one prediction for all its episodes: each decides as it does played alone (the
    committed world model; NOOP starts 0, 3 and 7), and an episode's decision ms include its share of the batch's."""
    from dynplan.models.chain import forget_greedy
    from dynplan.worlds.freeway.evaluation import Lockstep, world_model_for

    model, search, steps = world_model_for("learned"), ChickenSearch(horizon=4), 12
    episodes = [FreewayEpisode(mode=0, noop_start=n) for n in (0, 3, 7)]

    def actions(batch: list[FreewayEpisode]) -> list[list[int]]:
        forget_greedy()
        lockstep, out = Lockstep("learned", batch, search, list(range(len(batch))), model), [[] for _ in batch]
        for _ in range(steps):
            for i, turn in lockstep.advance():
                out[i].append(turn.action)
                assert turn.decision_ms > 0 and turn.frames.shape == (5, 154, 152)
        return out

    together = actions(episodes)
    assert together == [actions([episode])[0] for episode in episodes]
    assert all(len(a) == steps for a in together)
    with pytest.raises(ValueError, match="3 episodes and 2 seeds"):
        Lockstep("learned", episodes, search, [0, 1], model)
