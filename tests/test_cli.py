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

from dynplan.cli import run_command

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


@pytest.mark.parametrize("work", ["busy", "idle"])
def test_a_server_that_never_answers_is_named_after_its_own_cpu_time_or_the_wall_clock(work, monkeypatch, tmp_path):
    """The temporary server's start is bounded by its own CPU time (a loaded host stretches only the wall clock), and
    a server that waits without working by the wall clock; either way one error saying how long it was given."""
    from flows import cli

    monkeypatch.setattr(cli, "STARTUP_CPU_S", 1.0)
    monkeypatch.setattr(cli, "STARTUP_WALL_S", 600.0 if work == "busy" else 2.0)
    body = "any(iter(int, 1))" if work == "busy" else "import time; time.sleep(600)"
    with (tmp_path / "log").open("w+b") as log:
        server = subprocess.Popen([sys.executable, "-c", f"print('starting', flush=True); {body}"], stdout=log)
        try:
            with pytest.raises(RuntimeError, match=r"did not answer in \d+ s \(\d+ s of its CPU time\): starting$"):
                cli._wait_until_healthy(server, f"http://127.0.0.1:{cli._free_port()}/api", log)
            used = cli._cpu_seconds(server)
        finally:
            server.kill()
            server.wait()
    assert used >= 1.0 if work == "busy" else used < 1.0


def test_an_unexpected_error_is_one_line_and_exit_1(monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", ["python -m flows.x"])
    with temporary_settings(updates={PREFECT_API_URL: "http://127.0.0.1:9/api"}), pytest.raises(SystemExit) as exit_:
        run_command(failing_main, "python -m flows.x")
    assert exit_.value.code == 1
    err = capsys.readouterr().err
    assert err == "python -m flows.x: error: RuntimeError: the disk is on fire (run with --debug for the traceback)\n"
    monkeypatch.setattr(sys, "argv", ["python -m flows.x", "--debug"])
    with temporary_settings(updates={PREFECT_API_URL: "http://127.0.0.1:9/api"}), pytest.raises(RuntimeError):
        run_command(failing_main, "python -m flows.x")


@pytest.mark.parametrize("module", ["collect", "build_datasets", "collect_train_eval", "evaluate", "replay", "train"])
def test_every_command_offers_debug(module):
    proc = subprocess.run([sys.executable, "-m", f"flows.{module}", "--help"], cwd=ROOT, capture_output=True,
                          text=True, timeout=120)  # fmt: skip
    assert proc.returncode == 0 and "--debug" in proc.stdout


#: What a command must not load before it answers `--help`, a usage error or a missing display: a newcomer waits
#: for none of it.
HEAVY = ("prefect", "torch", "dask", "xarray", "zarr", "numba")
#: Runs the command `sys.argv[1]` with the rest as its arguments, then prints its exit status and the HEAVY modules
#: it loaded.
PROBE = """
import runpy, sys
module = sys.argv.pop(1)
try:
    runpy.run_module(module, run_name="__main__")
except SystemExit as exit:
    print("status", exit.code)
print(sorted(m for m in {heavy!r} if m in sys.modules))
"""


def probe(*argv: str, env: dict | None = None) -> subprocess.CompletedProcess:
    code = PROBE.format(heavy=HEAVY)
    return subprocess.run([sys.executable, "-c", code, *argv], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=120)  # fmt: skip


#: Each flow's `--help` (every world's, for the commands every world shares) and a usage error of each.
ANSWERED_AT_ONCE = [
    ("flows.collect", "--help"), ("flows.collect", "--episodes", "0"),
    ("flows.evaluate", "--help"), ("flows.evaluate", "--episodes", "0"),
    ("flows.evaluate", "--world", "freeway", "--help"), ("flows.evaluate", "--world", "minigrid", "--help"),
    ("flows.replay", "--help"), ("flows.replay", "--world", "freeway", "--help"), ("flows.replay",),
    ("flows.build_datasets", "--help"), ("flows.build_datasets", "--bogus"),
    ("flows.train", "--help"), ("flows.train", "nosuchstage"),
    ("flows.collect_train_eval", "--help"), ("flows.collect_train_eval", "--preset", "nosuch"),
    ("flows.view", "--help"), ("flows.view",), ("flows.play", "--help"),
]  # fmt: skip


@pytest.mark.parametrize("argv", ANSWERED_AT_ONCE, ids=" ".join)
def test_a_flow_answers_help_and_a_usage_error_before_loading_prefect_or_torch(argv):
    proc = probe(*argv)
    assert proc.stdout.splitlines()[-2:] == [f"status {0 if '--help' in argv else 2}", "[]"], proc.stdout[-500:]


def test_a_usage_error_is_one_line_naming_the_bad_value():
    proc = subprocess.run([sys.executable, "-m", "flows.collect", "--episodes", "0"], cwd=ROOT, env=without_api(),
                          capture_output=True, text=True, timeout=120)  # fmt: skip
    assert proc.returncode == 2 and proc.stderr.strip().count("\n") == 0, proc.stderr
    assert "--episodes=0 is invalid" in proc.stderr


def test_play_without_a_display_says_so_in_one_line_before_loading_a_world():
    proc = probe("flows.play", env={k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")})
    assert proc.stdout.splitlines() == ["status 2", "[]"], proc.stdout + proc.stderr
    assert proc.stderr.strip().count("\n") == 0 and "no display" in proc.stderr, proc.stderr


#: A command that will not stop when interrupted: it swallows the interrupt (as a busy library may) or leaves a
#: thread running that the interpreter waits for at exit.
_STUBBORN = """
import sys, threading, time
import dynplan.cli as cli
cli.STOP_WITHIN_S = 1.0
def swallows(argv):
    print("ready", file=sys.stderr, flush=True)
    while True:
        try:
            time.sleep(60)
        except KeyboardInterrupt:
            pass
def lingers(argv):
    threading.Thread(target=time.sleep, args=(600,)).start()
    print("ready", file=sys.stderr, flush=True)
    time.sleep(600)
cli.run_command({"swallows": swallows, "lingers": lingers}[sys.argv[1]], "python -m stubborn")
"""


@pytest.mark.parametrize("how", ["swallows", "lingers"])
def test_an_interrupted_command_ends_within_its_grace_however_busy(how):
    """Ctrl-C ends every command: a clean stop first, and after `STOP_WITHIN_S` (1 s here) the process ends with
    status 130 and one "interrupted" line, whatever its threads or libraries do with the interrupt."""
    proc = subprocess.Popen([sys.executable, "-c", _STUBBORN, how], cwd=ROOT, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))  # fmt: skip
    try:  # (the child takes SIGINT as a terminal sends it, even where this test runs with it ignored)
        assert proc.stderr.readline().strip() == "ready"
        proc.send_signal(signal.SIGINT)
        err = proc.communicate(timeout=60)[1]
    finally:
        proc.kill()
    assert proc.returncode == 130 and err.strip().splitlines() == [
        "python -m stubborn: interrupted; run it again to resume"
    ]
