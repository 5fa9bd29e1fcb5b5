"""Recording and the Zarr frames store: idempotent collection, incremental builds, readers, torch datasets."""

import shutil

import dask.array as da
import numpy as np
import pytest
import torch
import xarray as xr
import zarr

from dynplan.data.build import build_frame_store_from_logs
from dynplan.data.collect import log_path, record_episode
from dynplan.data.datasets import FrameDataset, WindowDataset, is_validation
from dynplan.data.store import list_logs
from dynplan.env import RoadConfig, generate_world
from dynplan.evaluation.agent import AgentSpec
from dynplan.logs import LogError, read_episode_log

RECORDING = RoadConfig(agent_speed=0.5)


def snapshot(folder):
    """Every file under `folder` with its bytes and modification time."""
    return {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in sorted(folder.rglob("*")) if p.is_file()}


def test_record_episode_is_idempotent_and_repairs_damage(tmp_path):
    first = record_episode(tmp_path, 3)
    assert first.status == "written" and first.path == str(log_path(tmp_path, 3))
    before = snapshot(tmp_path)
    assert record_episode(tmp_path, 3).status == "skipped"
    assert snapshot(tmp_path) == before
    path = log_path(tmp_path, 3)
    path.write_bytes(path.read_bytes()[:1000])  # damaged under its final name
    assert record_episode(tmp_path, 3).status == "rewritten"
    np.testing.assert_array_equal(read_episode_log(path).frames, generate_world(RECORDING, 3).frames)
    with pytest.raises(LogError, match="already holds seed 3 recorded with .* use another output folder"):
        record_episode(tmp_path, 3, RoadConfig(level=4, agent_speed=0.5))


def test_store_round_trip_and_standard_readers(tmp_path, recorded_logs):
    store = tmp_path / "frames.zarr"
    report = build_frame_store_from_logs(store, list_logs(recorded_logs))
    assert report.episodes == 6 and len(report.added) == 6 and not report.failed
    group = zarr.open_group(str(store), mode="r")
    assert list(group["seed"][:]) == list(range(6))
    for i in range(6):
        world = generate_world(RECORDING, i)
        np.testing.assert_array_equal(group["frames"][i], world.frames)
        np.testing.assert_array_equal(group["goal"][i], world.goal)
    assert group["frames"].chunks == (1, 407, 48, 48)
    assert group.attrs["n_frames"] == 407 and group.attrs["config"] == RECORDING.model_dump()
    ds = xr.open_zarr(store)
    assert ds["frames"].dims == ("episode", "time", "y", "x") and ds.sizes["episode"] == 6
    np.testing.assert_array_equal(ds["frames"][2].values, generate_world(RECORDING, 2).frames)
    assert ds["log_name"].values[0] == "episode_0000000000.mcap"
    frames = da.from_zarr(str(store), component="frames")
    assert frames.shape == (6, 407, 48, 48) and int(frames.sum().compute()) == int(group["frames"][:].sum())


def test_rebuild_is_a_no_op_and_new_logs_are_appended(tmp_path, recorded_logs):
    logs = tmp_path / "logs"
    logs.mkdir()
    for path in list_logs(recorded_logs)[:4]:
        shutil.copy(path, logs)
    store = tmp_path / "frames.zarr"
    build_frame_store_from_logs(store, list_logs(logs))
    before = snapshot(store)
    again = build_frame_store_from_logs(store, list_logs(logs))
    assert again.added == [] and len(again.skipped) == 4 and again.episodes == 4
    assert snapshot(store) == before  # identical store, nothing rewritten
    for path in list_logs(recorded_logs)[4:]:
        shutil.copy(path, logs)
    grown = build_frame_store_from_logs(store, list_logs(logs))
    assert len(grown.added) == 2 and grown.episodes == 6
    whole = tmp_path / "whole.zarr"
    build_frame_store_from_logs(whole, list_logs(recorded_logs))
    a, b = zarr.open_group(str(store), mode="r"), zarr.open_group(str(whole), mode="r")
    for name in ("frames", "goal", "seed", "log_name", "log_sha256"):
        np.testing.assert_array_equal(a[name][:], b[name][:])


def test_corrupt_and_mismatched_logs_are_reported_and_skipped(tmp_path, recorded_logs):
    logs = tmp_path / "logs"
    shutil.copytree(recorded_logs, logs)
    broken = logs / "broken.mcap"
    broken.write_bytes(log_path(recorded_logs, 0).read_bytes()[:5000])
    record_episode(tmp_path / "other", 9, RoadConfig(level=2, agent_speed=0.5))
    shutil.copy(log_path(tmp_path / "other", 9), logs / "level2.mcap")
    report = build_frame_store_from_logs(tmp_path / "frames.zarr", list_logs(logs))
    assert report.episodes == 6
    assert set(report.failed) == {str(broken), str(logs / "level2.mcap")}
    assert report.failed[str(broken)].startswith(f"{broken}: truncated or corrupt")
    assert "but the store holds" in report.failed[str(logs / "level2.mcap")]


def test_interrupted_append_is_rolled_back(tmp_path, recorded_logs, monkeypatch):
    import dynplan.data.build as store_module

    store = tmp_path / "frames.zarr"
    logs = list_logs(recorded_logs)
    build_frame_store_from_logs(store, logs[:2])
    original = store_module.da.store

    def crash(*args, **kwargs):
        raise KeyboardInterrupt("killed mid-append")

    monkeypatch.setattr(store_module.da, "store", crash)
    with pytest.raises(KeyboardInterrupt):
        build_frame_store_from_logs(store, logs)
    monkeypatch.setattr(store_module.da, "store", original)
    report = build_frame_store_from_logs(store, logs)
    assert report.episodes == 6 and len(report.added) == 4
    group = zarr.open_group(str(store), mode="r")
    assert group["frames"].shape[0] == group["goal"].shape[0] == group["seed"].shape[0] == 6
    assert list(group["seed"][:]) == list(range(6))


def test_missing_log_folder_is_named():
    with pytest.raises(FileNotFoundError, match="nowhere: no such folder of episode logs"):
        list_logs("nowhere")


def test_torch_datasets_split_by_episode(tmp_path, recorded_logs):
    store = tmp_path / "frames.zarr"
    build_frame_store_from_logs(store, list_logs(recorded_logs))
    train = FrameDataset(store, "train", val_fraction=0.3)
    validation = FrameDataset(store, "validation", val_fraction=0.3)
    assert set(train.episodes).isdisjoint(validation.episodes)
    assert sorted([*train.episodes, *validation.episodes]) == list(range(6))
    assert len(train) == len(train.episodes) * 407
    frame = train[407 + 10]
    assert frame.dtype == torch.uint8 and frame.shape == (48, 48)
    np.testing.assert_array_equal(frame.numpy(), generate_world(RECORDING, int(train.episodes[1])).frames[10])

    windows = WindowDataset(store, "all")
    assert len(windows) == 6 * (407 - 4)
    context, target = windows[403 + 7]  # episode 1, window starting at frame 7
    frames = generate_world(RECORDING, 1).frames
    np.testing.assert_array_equal(context.numpy(), frames[7:11])
    np.testing.assert_array_equal(target.numpy(), frames[11])
    with pytest.raises(IndexError):
        windows[len(windows)]
    # A longer context than the first decision has seen: its windows start at the first predicted frame (5), their
    # history padded with frame 0, as the world model pads a short observation.
    long = WindowDataset(store, "all", context=8)
    assert len(long) == 6 * (407 - 5) and long.target(402 + 3) == (1, 8)
    context, target = long[402]  # episode 1, target frame 5
    np.testing.assert_array_equal(context.numpy(), frames[[0, 0, 0, 0, 1, 2, 3, 4]])
    np.testing.assert_array_equal(target.numpy(), frames[5])
    np.testing.assert_array_equal(long[402 + 3][0].numpy(), frames[0:8])
    with pytest.raises(ValueError, match="split must be"):
        FrameDataset(store, "test")
    with pytest.raises(KeyError, match="no array 'codes'"):
        FrameDataset(store, array="codes")


def test_validation_split_is_stable_and_about_the_requested_fraction():
    seeds = np.arange(20_000)
    assert is_validation(seeds, 0.1).mean() == pytest.approx(0.1, abs=0.01)
    assert (is_validation(seeds[:100], 0.1) == is_validation(seeds, 0.1)[:100]).all()
    with pytest.raises(ValueError, match=r"val_fraction must be in \[0, 1\)"):
        is_validation(seeds, 1.0)


def test_replays_and_second_logs_of_a_seed_are_refused(tmp_path, recorded_logs):
    from dynplan.evaluation.replay import replay
    from dynplan.logs import write_episode_log

    logs = tmp_path / "logs"
    shutil.copytree(recorded_logs, logs)
    replay(log_path(logs, 1), AgentSpec(technique="random"), out=logs / "episode_1.replay.mcap")
    world = read_episode_log(log_path(logs, 2)).world()
    altered = world.frames.copy()
    altered[100, 0, 0] = 144  # same seed and geometry, different content
    write_episode_log(logs / "other_2.mcap", type(world)(world.config, 2, altered, world.goal, world.agent_start))
    report = build_frame_store_from_logs(tmp_path / "frames.zarr", list_logs(logs))
    assert report.episodes == 6
    assert (
        "a log of kind 'agent' (a replay), not a recorded world" in report.failed[str(logs / "episode_1.replay.mcap")]
    )
    assert "seed 2 is already in the store (episode_0000000002.mcap)" in report.failed[str(logs / "other_2.mcap")]
