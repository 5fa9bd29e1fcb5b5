"""MiniGrid Dynamic-Obstacles through the same logs and frames store as every world: an episode is the package's
room without the agent — walls and goal fixed, every ball a step of its random walk each frame, the same frames from
the same seed — written to MCAP and read back exactly, and `flows.collect --world minigrid` and
`flows.build_datasets` store and verify it. The agent turns and moves as MiniGrid's and is judged by the paper's
rule; judging many sequences against many futures is judging each; the futures each technique assumes keep the
balls; the planner with the true future reaches the goal."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from dynplan.config import ConfigError
from dynplan.data.collect import log_path, record_episode
from dynplan.logs.reader import read_episode_log
from dynplan.world import world, world_names

pytest.importorskip("minigrid")  # the `minigrid` extra, in `dev`: installed wherever the suite runs

from dynplan.worlds.minigrid import futures as techniques
from dynplan.worlds.minigrid.agent import AGENT_START_POSE, FORWARD, LEFT, RIGHT, Outcome, Pose, roll, step
from dynplan.worlds.minigrid.grid import PIXEL_VALUES, MiniGridConfig, record_world
from dynplan.worlds.minigrid.search import GridSearch, plan_grid, sequences

MINIGRID = world("minigrid")
BALL, WALL, GOAL = PIXEL_VALUES["ball"], PIXEL_VALUES["wall"], PIXEL_VALUES["goal"]


@pytest.fixture(scope="module")
def room():
    return record_world(MiniGridConfig(), 3, 120)


def _balls(frame: np.ndarray) -> set[tuple[int, int]]:
    return {(int(r), int(c)) for r, c in zip(*np.nonzero(frame == BALL), strict=True)}


def test_the_world_is_registered_with_its_extra_and_seeds():
    assert "minigrid" in world_names() and MINIGRID.id == "minigrid-v1" and MINIGRID.extra == "minigrid"
    assert MINIGRID.values() == (0, 72, 144, 244) and MINIGRID.background == PIXEL_VALUES["floor"]
    with pytest.raises(ConfigError, match=r"seed=-1 is invalid for the minigrid world; valid range \[0, "):
        MINIGRID.check_seed(-1)


def test_a_recording_is_the_room_with_walls_and_goal_fixed_and_every_ball_walking(room):
    frames = room.frames
    assert frames.shape == (120, 16, 16) and frames.dtype == np.uint8
    assert set(np.unique(frames).tolist()) == set(PIXEL_VALUES.values())
    border = np.ones((16, 16), bool)
    border[1:-1, 1:-1] = False
    assert (frames[:, border] == WALL).all() and (frames[:, 1, 14] == GOAL).all()  # the goal: bottom right
    assert np.array_equal(room.goal[0], [1, 14]) and np.array_equal(room.agent_start, [14, 1])  # agent: top left
    for before, after in itertools.pairwise(frames):
        old, new = _balls(before), _balls(after)
        assert len(old) == len(new) == 8 and old != new  # the balls walk every step
        for r, c in new:  # each ball one cell (a king's move) from where one was
            assert any(max(abs(r - r0), abs(c - c0)) <= 1 for r0, c0 in old)


def test_the_same_seed_gives_the_same_room_and_another_seed_another(room):
    assert np.array_equal(record_world(MiniGridConfig(), 3, 120).frames, room.frames)
    assert not np.array_equal(record_world(MiniGridConfig(), 4, 120).frames, room.frames)


def test_a_bad_room_is_refused_in_one_line():
    with pytest.raises(ValueError, match=r"obstacles=12 is invalid for size 16: MiniGrid places at most 8"):
        record_world(MiniGridConfig(obstacles=12), 0, 2)
    with pytest.raises(ConfigError, match="size"):
        MiniGridConfig(size=3)


def test_an_episode_round_trips_through_its_log(tmp_path, room):
    record_episode(tmp_path, 3, n_frames=120, world_name="minigrid")
    log = read_episode_log(log_path(tmp_path, 3))
    assert np.array_equal(log.frames, room.frames) and np.allclose(log.goal, room.goal)
    first = log_path(tmp_path, 3).read_bytes()
    log_path(tmp_path, 3).unlink()
    record_episode(tmp_path, 3, n_frames=120, world_name="minigrid")
    assert log_path(tmp_path, 3).read_bytes() == first  # byte-reproducible


def test_the_commands_collect_store_and_verify_the_world(tmp_path):
    """`flows.collect --world minigrid` records rooms (its own options refused beside the road's), and
    `flows.build_datasets --world minigrid` stores them; `--verify` finds the store whole."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    import zarr

    logs, store = tmp_path / "logs", tmp_path / "rooms.zarr"

    def command(*args: str) -> subprocess.CompletedProcess:
        root = Path(__file__).resolve().parents[1]
        return subprocess.run([sys.executable, "-m", *args], cwd=root, capture_output=True, text=True, timeout=300)

    done = command("flows.collect", "--world", "minigrid", "--episodes", "3", "--seed", "7", "--out", str(logs),
                   "--json")  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout.splitlines()[-1])["written"] == 3
    level = command("flows.collect", "--world", "minigrid", "--level", "3", "--out", str(logs))
    assert level.returncode == 2 and "--level: the road world's, not --world minigrid's" in level.stderr
    built = command("flows.build_datasets", str(logs), "--world", "minigrid", "--out", str(store))
    assert built.returncode == 0, built.stderr
    group = zarr.open_group(str(store), mode="r")
    assert group.attrs["world"] == "minigrid" and group.attrs["episodes"] == 3
    assert group["frames"].shape[1:] == (257, 16, 16)
    verified = command("flows.build_datasets", "--verify", str(store), str(logs))
    assert verified.returncode == 0, verified.stderr


# -- the agent and its planner ---------------------------------------------------------------------------------
FLOOR = PIXEL_VALUES["floor"]


def _room(*balls: tuple[int, int]) -> np.ndarray:
    frame = np.full((16, 16), FLOOR, np.uint8)
    frame[[0, -1], :] = frame[:, [0, -1]] = WALL
    frame[1, 14] = GOAL
    for cell in balls:
        frame[cell] = BALL
    return frame


def test_the_rule_turns_moves_and_judges_a_step():
    empty = _room()
    assert step(Pose(5, 5, 0), LEFT, empty, empty) == (Pose(5, 5, 3), Outcome.RUNNING)  # right → up
    assert step(Pose(5, 5, 0), RIGHT, empty, empty) == (Pose(5, 5, 1), Outcome.RUNNING)  # right → down
    assert step(Pose(5, 5, 3), FORWARD, empty, empty) == (Pose(6, 5, 3), Outcome.RUNNING)  # up: row + 1
    assert step(Pose(5, 14, 0), FORWARD, empty, empty)[1] == Outcome.DEATH  # into the wall
    assert step(Pose(2, 14, 1), FORWARD, empty, empty) == (Pose(1, 14, 1), Outcome.GOAL)
    assert step(Pose(5, 5, 0), LEFT, empty, _room((5, 5)))[1] == Outcome.DEATH  # a ball onto the agent
    assert step(Pose(5, 5, 0), FORWARD, _room((5, 6)), _room((5, 5)))[1] == Outcome.DEATH  # swapped with a ball
    assert step(Pose(5, 5, 0), FORWARD, _room((5, 6)), _room((6, 7)))[1] == Outcome.RUNNING  # it moved away first


def test_rolling_many_sequences_is_stepping_each(room):
    rng = np.random.default_rng(0)
    seqs = rng.integers(0, 3, (20, 6))
    poses, outcomes = roll(np.array([AGENT_START_POSE]), seqs, room.frames[None, :7])
    for sequence, pose, outcome in zip(seqs, poses[:, 0], outcomes[:, 0], strict=True):
        now, ended = AGENT_START_POSE, Outcome.RUNNING
        for t, action in enumerate(sequence):
            if ended == Outcome.RUNNING:
                now, ended = step(now, int(action), room.frames[t], room.frames[t + 1])
        assert tuple(pose) == tuple(now) and Outcome(int(outcome)) == ended


def test_futures_keep_the_balls_and_the_walk_moves_each_a_kings_move(room):
    rng = np.random.default_rng(1)
    walked = techniques.walk(room.frames, 10, 4, 8, rng)
    assert walked.shape == (8, 5, 16, 16) and (walked[:, 0] == room.frames[10]).all()
    for future in walked:
        for before, after in itertools.pairwise(future):
            old, new = _balls(before), _balls(after)
            assert len(new) == 8 and all(any(max(abs(r - a), abs(c - b)) <= 1 for a, b in old) for r, c in new)
    for name in ("oracle", "stand_still", "constant_velocity"):
        seen = getattr(techniques, name)(room.frames, 10, 4)
        assert seen.shape == (1, 5, 16, 16) and all(len(_balls(f)) == 8 for f in seen[0]), name
    assert (techniques.oracle(room.frames, 10, 4)[0] == room.frames[10:15]).all()


def test_the_planner_with_the_true_future_reaches_the_goal(room):
    assert sequences(2).tolist() == [[a, b] for a in range(3) for b in range(3)]
    pose, outcome, t = AGENT_START_POSE, Outcome.RUNNING, 0
    while outcome == Outcome.RUNNING and t < len(room.frames) - 1:
        decision = plan_grid(pose, techniques.oracle(room.frames, t, 5), room.goal[0], GridSearch())
        pose, outcome = step(pose, decision.action, room.frames[t], room.frames[t + 1])
        t += 1
    assert outcome == Outcome.GOAL and t < 60


def test_an_evaluation_plays_each_technique_into_its_run_resumes_and_checks_its_rows(tmp_path, prefect_api, capsys):
    import json

    from dynplan.evaluation.store import Run
    from flows.evaluate import main

    argv = ["--world", "minigrid", "--techniques", "oracle", "stand_still", "random", "--episodes", "3",
            "--first-seed", "3000000", "--batch", "2", "--results-dir", str(tmp_path), "--run", "trial"]  # fmt: skip
    by = {r["technique"]: r for r in main(argv)}
    assert by["oracle"]["success"] == 1.0 and by["random"]["success"] == 0.0 and by["random"]["deaths"] == 3
    assert {r["episodes"] for r in by.values()} == {3}
    run = Run(tmp_path, "trial")
    rows = run.rows()
    assert len(rows) == 9 and run.manifest()["world"] == "minigrid-v1" and run.manifest()["settings"]["samples"] == 64
    main(argv)  # nothing left to play
    assert run.rows() == rows
    assert main([*argv, "--check"]) and capsys.readouterr().out.rstrip().endswith("every row of the run holds")
    lines = run.episodes_path.read_text().splitlines()
    at, oracle = next((i, r) for i, r in enumerate(rows) if r["technique"] == "oracle")
    lines[at] = json.dumps({**oracle, "actions": f"F{oracle['steps']}"}, separators=(",", ":"))  # into the wall
    run.episodes_path.write_text("\n".join(lines) + "\n")
    with pytest.raises(SystemExit) as stop:
        main([*argv, "--check"])
    (problem,) = capsys.readouterr().err.strip().splitlines()
    assert stop.value.code == 1 and f"technique=oracle seed={oracle['seed']}: its actions replay to death" in problem


def test_the_committed_evaluation_fits_its_schema_replays_and_is_the_pages_table():
    """The committed run: every row through the schema, every 20th played again in its room, and each technique's
    success ± standard error as docs/minigrid.md shows it."""
    from pathlib import Path

    from dynplan.evaluation.store import Run, check_store
    from dynplan.worlds.minigrid.evaluation import summarise
    from dynplan.worlds.minigrid.results import replay_check

    root = Path(__file__).resolve().parents[1]
    store = root / "datasets" / "results" / "minigrid"
    check_store(store)
    run = Run(store)
    rows, settings = run.current(), run.manifest()["settings"]
    assert len(rows) == 1600 and settings["samples"] == 64
    assert [replay_check(row, settings) for row in rows[::20]] == [None] * 80
    learned = [row for row in rows if row["model"] is not None]
    assert len(learned) == 600 and {row["world_model_sha256"] for row in learned} == {
        run.manifest()["world_models"]["minigrid"]["weights_sha256"]
    }
    page = (root / "docs" / "minigrid.md").read_text()
    for line in summarise(rows):
        shown = f"{line['success']:.2f}" + (f" ± {line['se']:.2f}" if line["se"] else "")
        assert f"| {shown} | {line['deaths']} |" in page, line


def test_a_pipeline_the_world_has_no_preset_for_is_one_line(capsys, monkeypatch):
    """A world without pipeline presets (MiniGrid's parts without its own) is refused before any flow starts."""
    import dataclasses

    from dynplan.worlds.minigrid import parts
    from flows.collect_train_eval import main

    monkeypatch.setattr(parts, "PARTS", dataclasses.replace(parts.PARTS, presets={}))
    with pytest.raises(SystemExit) as stop:
        main(["--world", "minigrid", "--preset", "smoke", "--out", "unused"])
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert stop.value.code == 2 and line.endswith("error: preset 'smoke': the minigrid world has no pipeline presets")


@pytest.mark.usefixtures("headless_window")
def test_the_play_window_steers_the_agent_and_the_planner_plays_to_the_goal(tmp_path):
    pytest.importorskip("pygame")
    from flows.play import main

    keys = main(["--world", "minigrid", "--technique", "oracle", "--script", "d,w,w,a,w", "--scale", "4"])
    assert keys.turns == [RIGHT, FORWARD, FORWARD, LEFT, FORWARD] and keys.poses[-1][:2] == (12, 2)  # down 2, right 1
    out = tmp_path / "played.mcap"
    watched = main(["--world", "minigrid", "--technique", "oracle", "--watch", "--fps", "1000", "--scale", "4",
                    "--record", str(out), "--script", ",".join(["f"] * 80)])  # fmt: skip
    assert watched.outcomes[-1] == "goal" and not watched.running
    log = read_episode_log(out)
    assert list(log.agent.action) == watched.turns and log.agent.outcome[-1] == "goal"
    assert np.array_equal(log.agent.position[-1], [1, 14])  # the goal's cell
