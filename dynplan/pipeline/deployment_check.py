"""`python -m dynplan.pipeline.deployment_check [--preset smoke] [--out DIR]`: prove the deployment works
against a real Prefect server, the way a user drives it — start `prefect server start` on loopback (its own
PREFECT_HOME and database, a free port), serve the deployments with `python -m flows.serve`, trigger
`prefect deployment run collect-train-eval/<preset> --watch` with the CLI, wait for the run to complete, and
check that the report exists. Everything it starts is stopped on the way out; logs stay in DIR.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from contextlib import ExitStack
from pathlib import Path

from dynplan.cli import CommandParser, run_command


class DeploymentCheckError(RuntimeError):
    """A step of the check failed; the message says which and points at its log."""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait(what: str, ready, timeout: float, log: Path, proc: subprocess.Popen | None = None) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc is not None and proc.poll() is not None:
            raise DeploymentCheckError(f"{what}: exited with {proc.returncode}; see {log}")
        if ready():
            return
        time.sleep(1.0)
    raise DeploymentCheckError(f"{what}: not ready after {timeout:.0f} s; see {log}")


def _healthy(url: str) -> bool:
    return _found(f"{url}/health")


def _found(url: str) -> bool:
    """Whether the server answers `url` with 200 (asked over HTTP: a `prefect` command a second would cost a
    process start each)."""
    try:
        with urllib.request.urlopen(url, timeout=5) as response:
            return response.status == 200
    except OSError:  # an HTTPError (404: not yet) or no server
        return False


def run_check(out: Path, preset: str = "smoke", timeout: float = 900) -> Path:
    """Run the whole check; return the report's path (raises DeploymentCheckError on failure)."""
    out.mkdir(parents=True, exist_ok=True)
    port = _free_port()
    api = f"http://127.0.0.1:{port}/api"
    env = {
        **os.environ,
        "PREFECT_HOME": str(out / "prefect_home"),
        "PREFECT_API_URL": api,
        "PREFECT_SERVER_ANALYTICS_ENABLED": "false",
        "PREFECT_UI_ENABLED": "false",
    }
    prefect = str(Path(sys.executable).with_name("prefect"))
    with ExitStack() as stack:

        def start(name: str, *command: str) -> tuple[subprocess.Popen, Path]:
            log = out / f"{name}.log"
            stream = stack.enter_context(open(log, "w"))
            proc = subprocess.Popen(command, env=env, stdout=stream, stderr=subprocess.STDOUT)
            stack.callback(_stop, proc)
            return proc, log

        server, server_log = start("server", prefect, "server", "start", "--host", "127.0.0.1", "--port", str(port))
        _wait("prefect server", lambda: _healthy(api), 180, server_log, server)
        runs = out / "runs"
        serving, serve_log = start(
            "serve", sys.executable, "-m", "flows.serve", "--out", str(runs), "--presets", preset
        )
        name = f"collect-train-eval/{preset}"

        _wait(f"deployment {name}", lambda: _found(f"{api}/deployments/name/{name}"), 180, serve_log, serving)
        trigger = subprocess.run(
            [prefect, "deployment", "run", name, "--watch", "--watch-timeout", str(int(timeout))],
            env=env,
            capture_output=True,
            text=True,
        )
        (out / "trigger.log").write_text(trigger.stdout + trigger.stderr)
        if trigger.returncode != 0 or "Completed" not in trigger.stdout:
            raise DeploymentCheckError(f"flow run of {name} did not complete; see {out / 'trigger.log'}, {serve_log}")
    report = runs / preset / "report" / "report.md"
    if not report.exists():
        raise DeploymentCheckError(f"the run completed but wrote no report at {report}")
    return report


def _stop(proc: subprocess.Popen) -> None:
    proc.terminate()
    try:
        proc.wait(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()


def main(argv: list[str] | None = None) -> None:
    parser = CommandParser(prog="python -m dynplan.pipeline.deployment_check", description=__doc__)
    parser.add_argument("--preset", default="smoke", help="which deployment to trigger (default: smoke)")
    parser.add_argument("--out", help="working folder (default: a new temporary one)")
    args = parser.parse_args(argv)
    out = Path(args.out or tempfile.mkdtemp(prefix="dynplan-deploy-"))
    try:
        report = run_check(out, args.preset)
    except DeploymentCheckError as error:
        sys.exit(f"deployment check failed: {error}")
    print(f"deployment check passed: {report}")


if __name__ == "__main__":
    run_command(main, "python -m dynplan.pipeline.deployment_check")
