"""What every `python -m flows.…` command shares beside `dynplan.cli.run_command` (one line, not a traceback, for an
unexpected error unless `--debug`): a temporary Prefect API that dies with the command, started only when a flow is
about to run (after the arguments are parsed and checked: `--help` and a usage error answer before Prefect is
loaded), and a console showing Prefect's run lines only with `--verbose`.

Without `PREFECT_API_URL`, Prefect starts a temporary API server of its own, which outlives a command killed with
SIGKILL and may print shutdown errors when it is stopped before Prefect's log and event workers have flushed.
`temporary_api` starts that server itself, as a child that the kernel signals when the command dies (Linux's
parent-death signal), points Prefect at it, drains Prefect's workers and only then stops it.
"""

from __future__ import annotations

import argparse
import logging
import os
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import IO

from dynplan.cli import add_debug_option, die_with_parent

#: CPU seconds the temporary server may spend starting (a new `PREFECT_HOME` first creates its database) before it
#: is declared stuck: counted on the server's own clock, so a loaded host, which stretches the wall-clock start, does
#: not fail it.
STARTUP_CPU_S = 120.0
#: Wall-clock seconds at most, for a server that waits without working.
STARTUP_WALL_S = 900.0


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _drain_prefect() -> None:
    """Let Prefect's background workers send what they hold while the API is still up."""
    from prefect.events.worker import EventsWorker
    from prefect.logging.handlers import APILogWorker

    for worker in (APILogWorker, EventsWorker):
        with suppress(Exception):
            worker.drain_all(timeout=10)


def _last_line(log: IO[bytes]) -> str:
    log.seek(0)
    lines = log.read().decode(errors="replace").strip().splitlines()
    return f": {lines[-1]}" if lines else ""


def _cpu_seconds(server: subprocess.Popen) -> float:
    """The CPU time the server process has used so far (0 once it is gone)."""
    import psutil

    try:
        times = psutil.Process(server.pid).cpu_times()
    except psutil.Error:
        return 0.0
    return times.user + times.system


def _wait_until_healthy(server: subprocess.Popen, url: str, log: IO[bytes]) -> None:
    """Wait for the server's health check; a server that exits or does not answer after `STARTUP_CPU_S` of its own
    CPU time (or `STARTUP_WALL_S`) is a RuntimeError saying so."""
    import httpx

    started = time.monotonic()
    with httpx.Client() as client:
        while True:
            if server.poll() is not None:
                raise RuntimeError(
                    f"the temporary Prefect API server exited with status {server.returncode}{_last_line(log)}"
                )
            try:
                if client.get(f"{url}/health", timeout=2).status_code == 200:
                    return
            except httpx.HTTPError:
                pass
            waited = time.monotonic() - started
            if (used := _cpu_seconds(server)) > STARTUP_CPU_S or waited > STARTUP_WALL_S:
                raise RuntimeError(
                    f"the temporary Prefect API server did not answer in {waited:.0f} s"
                    f" ({used:.0f} s of its CPU time){_last_line(log)}"
                )
            time.sleep(0.1)


@contextmanager
def temporary_api() -> Iterator[str | None]:
    """Within the block, Prefect talks to `PREFECT_API_URL` if set, else to a temporary server of this process's
    own, stopped after the block (and signalled by the kernel if this process dies first). Yields the API's URL. The
    environment is checked first (`flows.environment`): a bad setting, an API that is not there, an unwritable home.
    The server's own output goes to a temporary file (its shutdown when the command is interrupted is no concern of
    the terminal's); its last line is told if it fails to start. The terminal shows what `_Console` lets through."""
    from flows.environment import checked_environment

    external = checked_environment()  # a bad PREFECT_* variable, API or home is named before anything runs
    import prefect
    from prefect.settings import PREFECT_API_URL, PREFECT_UI_URL, get_current_settings, temporary_settings

    _quiet_console()
    if external:
        yield external
        return
    port = _free_port()
    url = f"http://127.0.0.1:{port}/api"
    env = {
        **os.environ,
        "PREFECT_UI_ENABLED": "0",
        "PREFECT__SERVER_EPHEMERAL": "1",
        "PREFECT__SERVER_FINAL": "1",
        **get_current_settings().to_environment_variables(exclude_unset=True),
    }
    command = [
        sys.executable,
        "-m",
        "uvicorn",
        "--app-dir",
        str(Path(prefect.__file__).parent.parent),
        "--factory",
        "prefect.server.api.server:create_app",
        "--host",
        "127.0.0.1",
        "--port",
        str(port),
        "--log-level",
        "error",
        "--lifespan",
        "on",
    ]
    with tempfile.TemporaryFile() as log:
        server = subprocess.Popen(
            command, env=env, preexec_fn=die_with_parent, stdin=subprocess.DEVNULL, stdout=log, stderr=log
        )
        try:
            _wait_until_healthy(server, url, log)
            with temporary_settings(updates={PREFECT_API_URL: url, PREFECT_UI_URL: ""}):  # the server has no UI
                try:
                    yield url
                finally:
                    _drain_prefect()
        finally:
            server.terminate()
            try:
                server.wait(timeout=10)
            except subprocess.TimeoutExpired:
                server.kill()
                server.wait()


#: The start of Prefect's own messages of a run's life (not the flows' prints): shown with `--verbose`.
LIFECYCLE = ("Beginning flow run", "Beginning subflow run", "Finished in state", "Created task run", "View at")


class _Console(logging.Filter):
    """Keeps off the terminal (Prefect still sends all to its API) a failed task's or flow's report, unless
    `--debug` (the command says what went wrong in one line), and Prefect's messages of each run's life, unless
    `--verbose` (each stage prints its own line)."""

    def __init__(self, debug: bool, verbose: bool) -> None:
        super().__init__()
        self.debug, self.verbose = debug, verbose

    def filter(self, record: logging.LogRecord) -> bool:
        if not record.name.startswith(("prefect.task_runs", "prefect.flow_runs")):
            return True
        message = record.getMessage()
        failed = record.levelno >= logging.ERROR or "Finished in state Failed" in message
        if failed:
            return self.debug
        return self.verbose or not message.startswith(LIFECYCLE)


def _quiet_console() -> None:
    """Add `_Console` (as `--debug` and `--verbose` in the command line ask) to every terminal handler of Prefect's
    loggers and the root logger (which Prefect's logging configuration, read on importing `prefect.main`, gives its
    console handler)."""
    import prefect.main  # noqa: F401  (configures Prefect's logging, once)

    argv = sys.argv[1:]
    loggers = [logging.getLogger(name) for name in logging.root.manager.loggerDict if name.startswith("prefect")]
    for logger in [logging.root, *loggers]:
        for handler in logger.handlers:
            terminal = isinstance(handler, logging.StreamHandler) and not isinstance(handler, logging.FileHandler)
            if terminal and not any(isinstance(f, _Console) for f in handler.filters):
                handler.addFilter(_Console("--debug" in argv, "--verbose" in argv))


def add_console_options(parser: argparse.ArgumentParser) -> None:
    """`--debug` (the traceback of an unexpected error, and Prefect's reports of failed runs) and `--verbose`
    (Prefect's line for each run's start and end)."""
    add_debug_option(parser)
    parser.add_argument("--verbose", action="store_true", help="also print Prefect's line for each run's start and end")
