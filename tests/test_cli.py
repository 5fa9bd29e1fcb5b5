"""What every flow command shares: a temporary Prefect API that dies with the command, a quiet successful run, and
one line (or, with --debug, the traceback) for an unexpected error."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest
from prefect.settings import PREFECT_API_URL, temporary_settings

from flows.cli import run

ROOT = Path(__file__).resolve().parents[1]


def without_api() -> dict:
    """The environment of a user with no Prefect server configured."""
    return {k: v for k, v in os.environ.items() if k != "PREFECT_API_URL"}


def servers_of(pid: int) -> list[psutil.Process]:
    try:
        return [p for p in psutil.Process(pid).children(recursive=True) if "uvicorn" in " ".join(p.cmdline())]
    except psutil.NoSuchProcess:
        return []


@pytest.mark.slow
def test_a_successful_run_is_quiet_and_leaves_no_server(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "flows.collect", "--episodes", "2", "--out", str(tmp_path / "logs")],
                          cwd=ROOT, env=without_api(), capture_output=True, text=True, timeout=300)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    for noise in ("Traceback", "CancelledError", "Error flushing", "ERROR", "View at"):
        assert noise not in proc.stderr, proc.stderr[-3000:]
    assert "2 written" in proc.stderr + proc.stdout


@pytest.mark.slow
def test_a_killed_command_takes_its_temporary_server_with_it(tmp_path):
    command = [sys.executable, "-m", "flows.collect", "--episodes", "400", "--out", str(tmp_path / "logs")]
    proc = subprocess.Popen(command, cwd=ROOT, env=without_api(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    while not (servers := servers_of(proc.pid)) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert servers, "the command started no temporary Prefect server"
    while not any((tmp_path / "logs").glob("*.mcap")) and time.monotonic() < deadline:
        time.sleep(0.2)  # killed while the flow runs
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    _, alive = psutil.wait_procs(servers, timeout=30)
    assert not alive, [p.cmdline() for p in alive]


def failing_main(argv=None):
    raise RuntimeError("the disk is on fire")


def test_an_unexpected_error_is_one_line_and_exit_1(monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", ["python -m flows.x"])
    with temporary_settings(updates={PREFECT_API_URL: "http://127.0.0.1:9/api"}), pytest.raises(SystemExit) as exit_:
        run(failing_main, "python -m flows.x")
    assert exit_.value.code == 1
    err = capsys.readouterr().err
    assert err == "python -m flows.x: error: RuntimeError: the disk is on fire (run with --debug for the traceback)\n"
    monkeypatch.setattr(sys, "argv", ["python -m flows.x", "--debug"])
    with temporary_settings(updates={PREFECT_API_URL: "http://127.0.0.1:9/api"}), pytest.raises(RuntimeError):
        run(failing_main, "python -m flows.x")


@pytest.mark.parametrize("module", ["collect", "build_datasets", "collect_train_eval", "evaluate", "replay", "train"])
def test_every_command_offers_debug(module):
    proc = subprocess.run([sys.executable, "-m", f"flows.{module}", "--help"], cwd=ROOT, capture_output=True,
                          text=True, timeout=120)  # fmt: skip
    assert proc.returncode == 0 and "--debug" in proc.stdout
