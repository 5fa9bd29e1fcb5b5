"""Shared test settings and fixtures: hypothesis profiles, a Prefect API, recorded logs, a Dask cluster."""

import json
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import NamedTuple

# Prefect configures its logging once, on importing prefect.main: here, before any test captures output, so that its
# console handler writes to pytest's own stream, not to a test's capture closed after it.
import prefect.main  # noqa: F401
import pytest
from hypothesis import HealthCheck, settings

if os.environ.get("PYTEST_XDIST_WORKER_COUNT"):  # the workers share the cores: torch's threads too
    import torch

    torch.set_num_threads(max(1, (os.cpu_count() or 1) // int(os.environ["PYTEST_XDIST_WORKER_COUNT"])))

settings.register_profile("dev", max_examples=25, deadline=None)
settings.register_profile("ci", max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("ci" if os.environ.get("CI") else "dev")


@pytest.fixture(scope="session", autouse=True)
def prefect_api():
    """One throwaway Prefect API (temporary database) per test process, for the flows tests run in-process and,
    through `PREFECT_API_URL`, for the commands they start: a command's own temporary API server costs about 6 s of
    CPU. A test of that temporary server runs its command without the variable (`tests/test_cli.py::without_api`)."""
    from prefect.settings import PREFECT_API_URL
    from prefect.testing.utilities import prefect_test_harness

    with prefect_test_harness(server_startup_timeout=600):
        before = os.environ.get("PREFECT_API_URL")
        os.environ["PREFECT_API_URL"] = PREFECT_API_URL.value()
        try:
            yield
        finally:
            if before is None:
                os.environ.pop("PREFECT_API_URL", None)
            else:
                os.environ["PREFECT_API_URL"] = before


@pytest.fixture(scope="session")
def recorded_logs(tmp_path_factory) -> Path:
    """Six 407-frame episode logs (seeds 0–5), written once per test run; tests must not modify them."""
    from dynplan.data.collect import record_episode

    out = tmp_path_factory.mktemp("logs")
    for seed in range(6):
        record_episode(out, seed)
    return out


class DaskCluster(NamedTuple):
    address: str
    logs: Path  # folder with scheduler.log and worker*.log


@pytest.fixture(scope="session")
def dask_cluster(tmp_path_factory) -> Iterator[DaskCluster]:
    """A real dask.distributed cluster on loopback: a scheduler and two one-thread workers, each a process."""
    folder = tmp_path_factory.mktemp("dask")
    scheduler_file = folder / "scheduler.json"
    dask = str(Path(sys.executable).with_name("dask"))
    common = ["--dashboard-address", ":0", "--host", "127.0.0.1"]
    procs: list[subprocess.Popen] = []

    def start(log_name: str, *args: str) -> None:
        with open(folder / log_name, "w") as log:  # the child keeps its own handle
            procs.append(subprocess.Popen([dask, *args, *common], stdout=subprocess.DEVNULL, stderr=log))

    try:
        start("scheduler.log", "scheduler", "--port", "0", "--scheduler-file", str(scheduler_file))
        deadline = time.monotonic() + 60
        while not scheduler_file.exists() and time.monotonic() < deadline:
            time.sleep(0.2)
        address = json.loads(scheduler_file.read_text())["address"]
        for i in range(2):
            start(
                f"worker{i}.log",
                "worker",
                "--scheduler-file",
                str(scheduler_file),
                "--nworkers",
                "1",
                "--nthreads",
                "1",
            )
        from distributed import Client

        with Client(address, timeout=60) as client:
            client.wait_for_workers(2, timeout=120)
        yield DaskCluster(address, folder)
    finally:
        for proc in reversed(procs):
            proc.terminate()
        for proc in procs:
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()


@pytest.fixture
def headless_window(monkeypatch):
    """pygame windows open on SDL's dummy video and audio drivers (the play tests feed them real key events)."""
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    monkeypatch.setenv("SDL_AUDIODRIVER", "dummy")


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The files that hold slow tests first (each file's tests together, its fixtures built once), so that the workers
    share the long tests out and none is left alone at the end."""
    slow_files = {item.path for item in items if item.get_closest_marker("slow")}
    items.sort(key=lambda item: item.path not in slow_files)


def pytest_xdist_auto_num_workers(config: pytest.Config) -> int:
    """One worker more than the cores (`-n auto`): while one waits on a server or a command's start, the others
    compute."""
    return (os.cpu_count() or 1) + 1
