"""MiniGrid's learned world model and what plans with it: the committed tokenizer is exact on rooms; the prior's
imagined futures start from the room now, keep its walls and goal, are reproducible and have learned the balls'
walk (its chances of a ball sum to the balls there are, all within a king's move of one); planning against chances
is planning against futures when the chances are certain; a learned row names its weights; the replay command, the
presets and the pipeline (smoke, then a cache hit) take the world like any other."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

pytest.importorskip("minigrid")  # the `minigrid` extra, in `dev`: installed wherever the suite runs

from dynplan.worlds.minigrid import futures
from dynplan.worlds.minigrid.agent import AGENT_START_POSE, Outcome, roll, roll_chances
from dynplan.worlds.minigrid.grid import PIXEL_VALUES, MiniGridConfig, record_world
from dynplan.worlds.minigrid.imagine import MiniGridModel
from dynplan.worlds.minigrid.search import GridSearch, plan_chances, plan_grid, sequences

BALL, WALL, GOAL = PIXEL_VALUES["ball"], PIXEL_VALUES["wall"], PIXEL_VALUES["goal"]


@pytest.fixture(scope="module")
def room():
    return record_world(MiniGridConfig(), 3_000_001, 60)


@pytest.fixture(scope="module")
def model():
    return MiniGridModel()


def test_the_committed_tokenizer_encodes_and_decodes_rooms_exactly(room, model):
    with torch.inference_mode():
        codes = model.tokenizer.encode(torch.from_numpy(room.frames))
        decoded = model.tokenizer.decode(codes).numpy()
    assert codes.shape == (len(room.frames), 8, 8) and np.array_equal(decoded, room.frames)


def test_imagined_futures_start_now_keep_the_room_and_are_reproducible(room, model):
    seen = room.frames[:11]
    imagined = model.imagine(seen, 5, 6)
    assert imagined.rooms.shape == imagined.balls.shape == (6, 6, 16, 16)
    assert (imagined.rooms[:, 0] == seen[-1]).all() and (imagined.balls[:, 0] == (seen[-1] == BALL)).all()
    fixed = (seen[-1] == WALL) | (seen[-1] == GOAL)
    assert (imagined.rooms[..., fixed] == seen[-1][fixed]).all()  # walls and goal where they are, in every future
    assert imagined.balls.min() >= 0.0 and imagined.balls.max() <= 1.0 + 1e-6
    assert imagined.balls[..., fixed].max() < 0.01
    again = model.imagine(seen, 5, 6)
    assert np.array_equal(again.rooms, imagined.rooms) and np.array_equal(again.balls, imagined.balls)
    assert not np.array_equal(imagined.rooms[0], imagined.rooms[1])  # the samples differ: the future is uncertain


def test_the_prior_has_learned_the_walk(room, model):
    """Golden statistics of the next room over 40 samples at each of 10 steps: its chances of a ball sum to the 8
    balls, all but a sliver of them within a king's move of a ball now, and as spread as the true rule's."""
    counts, outside, spread = [], [], []
    for t in range(10, 20):
        now = room.frames[t]
        chances = model.imagine(room.frames[: t + 1], 1, 40).balls[:, 1].mean(axis=0)
        near = np.zeros_like(now, bool)
        for r, c in np.argwhere(now == BALL):
            near[max(r - 1, 0) : r + 2, max(c - 1, 0) : c + 2] = True
        counts.append(chances.sum())
        outside.append(chances[~near].sum())
        spread.append((chances > 0.02).sum() / (now == BALL).sum())
    assert abs(np.mean(counts) - 8) < 0.3 and np.max(outside) < 0.1
    assert 4.0 < np.mean(spread) < 9.0  # about 7 free neighbours a ball: the walk, not a guess of one step


def test_planning_against_certain_chances_is_planning_against_futures(room):
    rng = np.random.default_rng(0)
    walked = futures.walk(room.frames, 20, 4, 7, rng)
    seqs = sequences(4)
    layout = np.where(room.frames[20] == BALL, PIXEL_VALUES["floor"], room.frames[20])
    for pose in (AGENT_START_POSE, (8, 8, 1), (2, 13, 0)):
        poses, outcomes = roll(np.array([pose]), seqs, walked)
        rolled = roll_chances(tuple(pose), seqs, layout, (walked == BALL).astype(np.float32))
        assert np.array_equal(rolled.won == 1.0, outcomes == Outcome.GOAL)
        assert np.array_equal(rolled.died == 1.0, outcomes == Outcome.DEATH)
        assert set(np.unique(rolled.won + rolled.died)) <= {0.0, 1.0}
        running = outcomes == Outcome.RUNNING
        assert np.array_equal(rolled.poses[running], poses[running])
        search = GridSearch(horizon=4)
        hard = plan_grid(tuple(pose), walked, room.goal[0], search)
        soft = plan_chances(tuple(pose), layout, (walked == BALL).astype(np.float32), room.goal[0], search)
        assert hard.action == soft.action and np.allclose(hard.values, soft.values)


def test_a_learned_row_names_its_world_model_and_weights():
    from pydantic import ValidationError

    from dynplan.worlds.minigrid.results import MiniGridRow

    row = {"technique": "learned10", "model": "minigrid", "seed": 1, "outcome": "goal", "steps": 2,
           "decision_ms": 20.0, "actions": "F2", "code_version": "x", "world_model_sha256": "ab"}  # fmt: skip
    MiniGridRow(**row)
    for broken in ({"model": None}, {"world_model_sha256": None}):
        with pytest.raises(ValidationError, match="technique 'learned10' needs a model and its world_model_sha256"):
            MiniGridRow(**{**row, **broken})
    with pytest.raises(ValidationError, match="technique 'walk' takes no model"):
        MiniGridRow(**{**row, "technique": "walk"})


def test_the_replay_command_plays_a_recorded_room_and_refuses_another_worlds_log(tmp_path, prefect_api, capsys):
    from dynplan.data.collect import log_path, record_episode
    from dynplan.logs.reader import read_episode_log
    from flows.replay import main

    log = log_path(tmp_path / "logs", 1_000_000)
    record_episode(tmp_path / "logs", 1_000_000, world_name="minigrid")
    out, gif = tmp_path / "replay.mcap", tmp_path / "replay.gif"
    result = main(["--world", "minigrid", str(log), "--technique", "learned5", "--out", str(out), "--gif", str(gif)])
    replay = read_episode_log(out)
    assert result["outcome"] in ("goal", "death", "timeout") and len(replay.agent.action) == result["steps"]
    assert sorted(replay.imagined) == list(range(result["steps"])) and replay.imagined[0].shape == (5, 16, 16)
    assert gif.stat().st_size > 0
    road_log = tmp_path / "road.mcap"
    record_episode(tmp_path / "road", 0, n_frames=20)
    log_path(tmp_path / "road", 0).rename(road_log)
    with pytest.raises(SystemExit) as stop:
        main(["--world", "minigrid", str(road_log), "--out", str(tmp_path / "x.mcap")])
    (line,) = capsys.readouterr().err.strip().splitlines()[-1:]
    assert stop.value.code != 0 and "is a road log" in line and "flows.collect --world minigrid" in line


def test_the_presets_are_valid_data():
    from dynplan.pipeline.presets import pipeline_preset

    quick, full, smoke = (pipeline_preset(n, "minigrid") for n in ("quick", "full", "smoke"))
    assert quick.folder == "minigrid-quick" and quick.models == ("minigrid",) and full.pretrained
    assert quick.learned_techniques == ("learned10", "learned1") and full.evaluation.episodes == 200
    assert smoke.pixelcnn_config("minigrid").channels == 8 and quick.vqvae_config("minigrid").world == "minigrid"


@pytest.mark.slow
def test_the_smoke_pipeline_runs_end_to_end_and_its_rerun_is_a_cache_hit(tmp_path, prefect_api):
    from flows.collect_train_eval import main

    report = main(["--world", "minigrid", "--preset", "smoke", "--out", str(tmp_path)])
    text = Path(report).read_text()
    assert "| oracle | 1 | 1.00 ± 0.00 |" in text and "| learned1 | 1 |" in text and "![episode](episode.gif)" in text
    folder = tmp_path / "minigrid-smoke"
    assert (folder / "report" / "episode.mcap").stat().st_size > 0
    gif = (folder / "report" / "episode.gif").stat().st_mtime_ns
    main(["--world", "minigrid", "--preset", "smoke", "--out", str(tmp_path)])
    stages = {s["name"]: s for s in json.loads((folder / "report" / "stages.json").read_text())}
    assert stages["vqvae [minigrid]"]["detail"].startswith("cached")
    assert stages["pixelcnn [minigrid]"]["detail"].startswith("cached")
    assert (folder / "report" / "episode.gif").stat().st_mtime_ns == gif  # drawn once for the same weights


@pytest.mark.slow
def test_the_benchmark_times_each_case_at_the_same_decisions():
    import subprocess
    import sys

    root = Path(__file__).resolve().parents[1]
    proc = subprocess.run(
        [sys.executable, "-m", "dynplan.bench", "minigrid", "--json"], cwd=root, capture_output=True, text=True
    )
    assert proc.returncode == 0, proc.stderr
    figures = json.loads(proc.stdout)
    decisions = {figures[case]["decisions"] for case in ("walk64", "learned10", "learned1", "search_only")}
    assert len(decisions) == 1 and decisions.pop() > 20
    assert 0 < figures["learned1"]["median_ms"] < figures["learned10"]["median_ms"]
    assert figures["learned10"]["ratio_walk64"] > 0 and "load_before" in figures["machine"]
