"""Freeway through the same logs and frames store as the road: a mode's recording is the world an episode with any
NOOP start sees (from frame n), it is written to MCAP and read back exactly, the same bytes each time, with the
world named in its record and no goal topic; `flows.collect --world freeway` is resumable and refuses what is not
its; the Zarr store holds its episodes without a goal array and `--verify` repairs it from the logs."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import zarr

from dynplan.config import ConfigError
from dynplan.data.build import build_frame_store_from_logs
from dynplan.data.collect import record_episode
from dynplan.data.store import fingerprint, list_logs
from dynplan.data.verify import verify_store
from dynplan.logs.format import TOPIC_FRAME, TOPIC_GOAL
from dynplan.logs.reader import LogError, inspect_log, read_episode_log
from dynplan.logs.recording import read_recorded_log
from dynplan.logs.writer import write_episode_log
from dynplan.world import DEFAULT_WORLD, world, world_names, world_of
from dynplan.worlds.freeway import game as freeway
from dynplan.worlds.freeway.game import FreewayEpisode, FreewayGame, record_mode

pytest.importorskip("ale_py")  # the `atari` extra, in `dev`: installed wherever the suite runs

ROOT = Path(__file__).resolve().parents[1]
ROAD, FREEWAY = world("road"), world("freeway")


@pytest.fixture(scope="module")
def mode_1() -> freeway.FreewayWorld:
    return record_mode(1, 120)


def test_the_registry_names_each_world_once_and_refuses_others():
    names = world_names()  # the default first, then the others by name: dynplan's, and any package's
    assert names[:2] == ["road", "freeway"] and len(set(names)) == len(names)
    assert world("road") is ROAD and world("freeway") is FREEWAY
    assert world("freeway").id == "freeway-v1" and DEFAULT_WORLD == "road"
    assert world_of(ROAD.recording) is ROAD and world_of(FREEWAY.recording) is FREEWAY
    with pytest.raises(ConfigError, match="'atari' is not one of dynplan's worlds: road, freeway"):
        world("atari")
    with pytest.raises(ConfigError, match=r"seed=8 is invalid for the freeway world; valid range \[0, 7\]"):
        FREEWAY.check_seed(8)


def test_a_modes_recording_is_what_every_noop_start_sees(mode_1):
    assert mode_1.frames.shape == (120, 154, 152) and mode_1.goal is None
    for noop_start in (0, 5):
        game = FreewayGame(FreewayEpisode(mode=1, noop_start=noop_start))
        seen = [game.world_frame()] + [game.step(int(a)).frame for a in np.random.default_rng(0).integers(0, 3, 30)]
        np.testing.assert_array_equal(np.stack(seen), mode_1.frames[noop_start : noop_start + 31])
    values = set(np.unique(mode_1.frames).tolist())
    assert values <= set(freeway.PIXEL_VALUES.values()) and len(values) >= 10


def test_a_freeway_log_reads_back_exactly_and_is_the_same_bytes(tmp_path, mode_1):
    first = write_episode_log(tmp_path / "a.mcap", mode_1)
    again = write_episode_log(tmp_path / "b.mcap", record_mode(1, 120))
    assert first.read_bytes() == again.read_bytes()
    log = read_episode_log(first)
    np.testing.assert_array_equal(log.frames, mode_1.frames)
    assert log.goal is None and log.entry is FREEWAY and log.seed == 1 and log.metadata["world"] == "freeway"
    assert TOPIC_GOAL not in inspect_log(first).topics and TOPIC_FRAME in inspect_log(first).topics
    np.testing.assert_array_equal(log.agent_start, [freeway.chicken_row(freeway.BOTTOM_Y), freeway.CHICKEN_COLUMN])
    assert read_recorded_log(first).seed == 1  # checked against a fresh recording of its mode


def test_a_freeway_log_with_a_value_outside_the_palette_or_an_unknown_world_is_refused(tmp_path, mode_1):
    frames = mode_1.frames.copy()
    frames[3, 10, 20] = 7
    bad = write_episode_log(tmp_path / "bad.mcap", freeway.FreewayWorld(mode_1.config, 1, frames))
    with pytest.raises(LogError, match=r"/world/frame message 3 has pixel value 7 at \(y 10, x 20\)"):
        read_episode_log(bad)
    other = freeway.FreewayWorld(mode_1.config, 1, record_mode(2, 120).frames)
    with pytest.raises(LogError, match="is not what seed 1 records: its frames differ.*--world freeway"):
        read_recorded_log(write_episode_log(tmp_path / "other.mcap", other))
    from mcap.writer import Writer

    path = tmp_path / "unknown.mcap"
    with open(path, "wb") as stream:
        writer = Writer(stream)
        writer.start()
        writer.add_metadata("dynplan", {"format": "dynplan.episode", "format_version": "1", "world": "pong",
                                        "config": "{}"})  # fmt: skip
        writer.finish()
    with pytest.raises(LogError, match="bad 'dynplan' metadata: world 'pong' is not one of dynplan's worlds"):
        read_episode_log(path)


def test_collecting_freeway_is_resumable_and_the_store_holds_it_without_a_goal(tmp_path):
    logs, store = tmp_path / "logs", tmp_path / "frames.zarr"
    assert [record_episode(logs, m, None, 60, "freeway").status for m in (0, 3)] == ["written", "written"]
    assert record_episode(logs, 3, None, 60, "freeway").status == "skipped"
    damaged = list_logs(logs)[1]
    damaged.write_bytes(damaged.read_bytes()[:-100])
    assert record_episode(logs, 3, None, 60, "freeway").status == "rewritten"
    with pytest.raises(LogError, match="in the freeway world; this run asks for seed 0.* in the road world"):
        record_episode(logs, 0, ROAD.recording, 60)

    report = build_frame_store_from_logs(store, list_logs(logs))
    assert len(report.added) == 2 and not report.failed
    group = zarr.open_group(str(store), mode="r")
    assert sorted(group.array_keys()) == ["frames", "log_name", "log_sha256", "seed"]
    assert group.attrs["world"] == "freeway" and group.attrs["pixel_values"] == freeway.PIXEL_VALUES
    np.testing.assert_array_equal(group["frames"][1], read_episode_log(list_logs(logs)[1]).frames)
    assert list(group["seed"][:]) == [0, 3]
    key = fingerprint(store)

    chunk = next(p for p in (store / "frames" / "c").rglob("*") if p.is_file())
    chunk.write_bytes(chunk.read_bytes()[:-8] + b"damaged!")
    assert [d.repaired for d in verify_store(store, logs).damage] == [True]
    assert not verify_store(store).damage and fingerprint(store) == key


def test_the_commands_take_the_world(tmp_path):
    """`flows.collect --world freeway` records modes, refuses the road's options and modes past 7;
    `flows.build_datasets` refuses a world's logs under another world's build."""
    logs = tmp_path / "logs"

    def command(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", *args], cwd=ROOT, capture_output=True, text=True, timeout=300)

    done = command("flows.collect", "--world", "freeway", "--seed", "6", "--out", str(logs), "--json")  # modes 6, 7
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout.splitlines()[-1])["written"] == 2
    assert [read_episode_log(p).seed for p in list_logs(logs)] == [6, 7]
    past = command("flows.collect", "--world", "freeway", "--seed", "7", "--episodes", "2", "--out", str(logs))
    assert past.returncode == 2 and "valid range [0, 7] (the game mode)" in past.stderr.splitlines()[-1]
    level = command("flows.collect", "--world", "freeway", "--level", "3", "--out", str(logs))
    assert level.returncode == 2 and "--level: the road world's, not --world freeway's" in level.stderr
    road = command("flows.build_datasets", str(logs), "--out", str(tmp_path / "road.zarr"))
    assert road.returncode == 1 and "a log of the freeway world; this build is --world road's" in road.stderr
    built = command("flows.build_datasets", str(logs), "--world", "freeway", "--out", str(tmp_path / "fw.zarr"))
    assert built.returncode == 0, built.stderr
    assert zarr.open_group(str(tmp_path / "fw.zarr"), mode="r").attrs["episodes"] == 2


def test_a_freeway_log_with_a_goal_topic_or_a_mode_past_7_is_refused(tmp_path, mode_1):
    from dynplan.env.road import World

    goal = np.zeros((len(mode_1.frames), 2))
    path = write_episode_log(tmp_path / "goal.mcap", World(mode_1.config, 1, mode_1.frames, goal, mode_1.agent_start))
    with pytest.raises(LogError, match="has a /world/goal topic, but the freeway world has no goal"):
        read_episode_log(path)
    beyond = write_episode_log(tmp_path / "mode9.mcap", freeway.FreewayWorld(mode_1.config, 9, mode_1.frames))
    with pytest.raises(LogError, match=r"bad 'dynplan' metadata: seed=9 is invalid for the freeway world; valid range"):
        read_episode_log(beyond)
    with pytest.raises(ConfigError, match="a FreewayEpisode is no world's config; the worlds' are RoadConfig, Freeway"):
        world_of(FreewayEpisode())


def test_an_abbreviated_world_is_not_taken_for_the_road():
    from flows.evaluate import main

    with pytest.raises(SystemExit) as exit_:
        main(["--worl", "freeway", "--techniques", "oracle"])
    assert exit_.value.code == 2
