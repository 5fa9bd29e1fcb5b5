"""The machine's errors are named, not unexpected: a bad `PREFECT_*` variable, an API that is not there or is not
Prefect's, a Prefect home that cannot be written, a full stdout, a path of another kind where a lock or a file goes,
a checkpoint that cannot be written. Each is one line naming the variable, the stream or the file, with no traceback
and no `--debug` hint, and nothing runs."""

from __future__ import annotations

import http.server
import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest
import torch

from dynplan.models import checkpoint

ROOT = Path(__file__).resolve().parents[1]


def _run(argv: list[str], env: dict[str, str], **streams) -> subprocess.CompletedProcess:
    base = {k: v for k, v in os.environ.items() if k not in ("PREFECT_API_URL", "PYTHONUNBUFFERED")}
    streams = streams or {"stdout": subprocess.PIPE, "stderr": subprocess.PIPE}
    return subprocess.run([sys.executable, "-m", *argv], cwd=ROOT, env={**base, **env}, text=True, timeout=300,
                          **streams)  # fmt: skip


def _one_line(done: subprocess.CompletedProcess, *named: str) -> str:
    lines = done.stderr.strip().splitlines()
    assert done.returncode in (1, 2) and len(lines) == 1, done.stderr
    assert "Traceback" not in done.stderr and "--debug" not in lines[0], lines
    assert all(n in lines[0] for n in named), lines[0]
    return lines[0]


@pytest.fixture(scope="module")
def not_prefect():
    """An HTTP server that is not Prefect's: it answers 404 to everything."""
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), http.server.BaseHTTPRequestHandler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    yield f"http://127.0.0.1:{server.server_address[1]}/api"
    server.shutdown()


@pytest.mark.parametrize(
    ("variable", "value", "said"),
    [
        ("PREFECT_LOGGING_LEVEL", "LOUD", "PREFECT_LOGGING_LEVEL='LOUD' is invalid"),
        ("PREFECT_API_URL", "not a url", "is not an http(s) URL"),
        ("PREFECT_API_URL", "http://127.0.0.1:9/api", "nothing answers there"),
        ("PREFECT_API_URL", "{not_prefect}", "answers, but not as a Prefect API"),
        ("PREFECT_HOME", "{a_file}", "cannot be written"),
    ],
)
def test_a_bad_prefect_environment_is_named_before_anything_runs(tmp_path, not_prefect, variable, value, said):
    (tmp_path / "a_file").write_text("not a folder")
    value = value.format(not_prefect=not_prefect, a_file=tmp_path / "a_file")
    done = _run(["flows.collect", "--out", str(tmp_path / "logs"), "--episodes", "1"], {variable: value})
    line = _one_line(done, variable, said)
    assert done.returncode == 2 and not (tmp_path / "logs").exists(), line


def test_a_full_stdout_is_named(tmp_path):
    with open("/dev/full", "w") as full:
        done = _run(["flows.build_datasets", "--help"], {}, stdout=full, stderr=subprocess.PIPE)
    assert done.returncode == 1 and done.stderr.strip().endswith("stdout: no space left on the device"), done.stderr


def test_a_lock_that_is_a_folder_is_named(tmp_path, recorded_logs, prefect_api):
    (tmp_path / "store.zarr.lock").mkdir()
    done = _run(["flows.build_datasets", str(recorded_logs), "--out", str(tmp_path / "store.zarr")],
                {"PREFECT_API_URL": os.environ["PREFECT_API_URL"]})  # fmt: skip
    _one_line(done, str(tmp_path / "store.zarr.lock"), "is a folder where a file is needed")


def test_a_checkpoint_that_cannot_be_written_names_its_file(tmp_path, monkeypatch):
    def full(*args, **kwargs):
        raise RuntimeError("[enforce fail at inline_container.cc:672] . PytorchStreamWriter failed writing file")

    monkeypatch.setattr(torch, "save", full)
    target = tmp_path / "vqvae.pt"
    with pytest.raises(OSError, match="could not be written") as raised:
        checkpoint.save(target, {"model": {"w": torch.zeros(2)}})
    assert raised.value.filename == str(target) and not list(tmp_path.iterdir())
