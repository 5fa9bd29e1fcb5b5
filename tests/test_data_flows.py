"""The collect-episodes and build-datasets flows: resumption after a crash, reruns, CLIs, a real Dask cluster."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import zarr

from dynplan.data.build import build_frame_store_from_logs
from dynplan.data.collect import log_path
from dynplan.data.store import list_logs
from dynplan.env import RoadConfig, generate_world
from dynplan.logs import read_episode_log

ROOT = Path(__file__).resolve().parents[1]


def run_cli(*args, timeout=600):
    proc = subprocess.run([sys.executable, "-m", *args], cwd=ROOT, capture_output=True, text=True, timeout=timeout)
    return proc


def test_collect_resumes_after_a_crash_without_losing_or_duplicating(tmp_path, prefect_api, monkeypatch):
    import dynplan.data.collect as collect_module
    from flows.collect import collect_episodes

    real_write = collect_module.write_episode_log

    def dies_on_seed_3(path, world, *args, **kwargs):
        if world.seed == 3:
            # What a killed writer leaves: a half-written temporary file, never the final name.
            (Path(path).parent / f".{Path(path).name}.crashed.tmp").write_bytes(b"\x89MCAP0\r\n partial")
            raise RuntimeError("worker killed while writing seed 3")
        return real_write(path, world, *args, **kwargs)

    monkeypatch.setattr(collect_module, "write_episode_log", dies_on_seed_3)
    with pytest.raises(RuntimeError, match="killed while writing seed 3"):
        collect_episodes(out=str(tmp_path), episodes=6, seed=0)
    assert not log_path(tmp_path, 3).exists()

    monkeypatch.setattr(collect_module, "write_episode_log", real_write)
    summary = collect_episodes(out=str(tmp_path), episodes=6, seed=0)
    assert summary["written"] + summary["skipped"] == 6 and summary["written"] >= 1
    files = sorted(p.name for p in tmp_path.iterdir())
    assert files == [log_path(tmp_path, s).name for s in range(6)]  # one log per seed; no temporaries left
    for seed in range(6):
        log = read_episode_log(log_path(tmp_path, seed))
        np.testing.assert_array_equal(log.frames, generate_world(RoadConfig(agent_speed=0.5), seed).frames)

    again = collect_episodes(out=str(tmp_path), episodes=6, seed=0)
    assert (again["written"], again["skipped"]) == (0, 6)


def test_build_datasets_flow_matches_the_library_and_reruns_idle(tmp_path, recorded_logs, prefect_api):
    from flows.build_datasets import build_datasets

    store = tmp_path / "flow.zarr"
    report = build_datasets(log_dir=str(recorded_logs), out=str(store))
    assert report["episodes"] == 6 and len(report["added"]) == 6
    rerun = build_datasets(log_dir=str(recorded_logs), out=str(store))
    assert rerun["added"] == [] and len(rerun["skipped"]) == 6
    library = tmp_path / "library.zarr"
    build_frame_store_from_logs(library, list_logs(recorded_logs))
    a, b = zarr.open_group(str(store), mode="r"), zarr.open_group(str(library), mode="r")
    for name in ("frames", "goal", "seed", "log_sha256"):
        np.testing.assert_array_equal(a[name][:], b[name][:])


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["flows.collect", "--episodes", "0"], "episodes=0 is invalid"),
        (["flows.collect", "--level", "-3"], "level=-3 is invalid"),
        (["flows.collect", "--agent-speed", "0"], "--agent-speed=0 is invalid; valid range (0.0, 8.0]"),
        (["flows.build_datasets", "no/such/logs"], "no/such/logs: no such folder of episode logs"),
    ],
)
def test_cli_rejects_bad_input_with_one_clear_line(args, message):
    proc = run_cli(*args, timeout=120)
    assert proc.returncode == 2
    assert message in proc.stderr


@pytest.mark.slow
def test_collect_and_build_on_a_real_dask_cluster_equal_a_local_run(tmp_path, dask_cluster):
    logs, store = tmp_path / "logs", tmp_path / "cluster.zarr"
    collect = run_cli("flows.collect", "--episodes", "4", "--seed", "20", "--out", str(logs),
                      "--dask-address", dask_cluster.address, "--json")  # fmt: skip
    assert collect.returncode == 0, collect.stderr[-3000:]
    assert json.loads(collect.stdout.strip().splitlines()[-1])["written"] == 4
    worker_logs = "".join(p.read_text() for p in dask_cluster.logs.glob("worker*.log"))
    assert worker_logs.count("Task run 'record-episode") >= 4  # the tasks ran on the cluster's workers
    build = run_cli(
        "flows.build_datasets", str(logs), "--out", str(store), "--dask-address", dask_cluster.address, "--json"
    )
    assert build.returncode == 0, build.stderr[-3000:]
    assert json.loads(build.stdout.strip().splitlines()[-1])["episodes"] == 4

    local_logs = tmp_path / "local"
    for seed in range(20, 24):
        from dynplan.data.collect import record_episode

        record_episode(local_logs, seed)
    local = tmp_path / "local.zarr"
    build_frame_store_from_logs(local, list_logs(local_logs))
    a, b = zarr.open_group(str(store), mode="r"), zarr.open_group(str(local), mode="r")
    for name in ("frames", "goal", "seed", "log_name", "log_sha256"):
        np.testing.assert_array_equal(a[name][:], b[name][:])
