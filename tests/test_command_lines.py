"""Every command speaks in one line: a usage error, a device node given as an output, a full disk, an unreachable
cluster; an interrupt is "interrupted" and exit status 130 (docs/robustness.md)."""

from __future__ import annotations

import errno
import os
import re
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest

import flows.collect
import flows.replay
from dynplan.cli import Bounded, CommandParser, bounded
from dynplan.data.collect import CollectPlan, record_episode
from dynplan.files import atomic_path, write_bytes_atomic
from dynplan.paths import PathError, PathKind, check_input, check_output, check_path

ROOT = Path(__file__).resolve().parents[1]
PYTHON = sys.executable


def _device_node(folder: Path) -> Path:
    node = folder / "node"
    try:
        os.mknod(node, 0o666 | stat.S_IFCHR, os.makedev(1, 3))
    except PermissionError:
        node.symlink_to("/dev/null")
    return node


def test_a_device_node_is_never_written(tmp_path, capsys):
    node = _device_node(tmp_path)
    with pytest.raises(PathError, match="is a character device; only regular files are written"):
        check_output(node, "--out")
    with pytest.raises(PathError, match="not a regular file"):
        write_bytes_atomic(node, b"x")
    log = record_episode(tmp_path / "logs", 3).path
    for option in ("--out", "--gif"):
        with pytest.raises(SystemExit) as stop:
            flows.replay.main(
                [log, option, str(node)] + (["--out", str(tmp_path / "r.mcap")] if option == "--gif" else [])
            )
        assert stop.value.code == 2
        assert f"{option} {node}: is a character device" in capsys.readouterr().err
    assert stat.S_ISCHR(node.stat().st_mode)  # still the node it was


def test_path_kinds_refuse_what_is_not_of_their_kind(tmp_path):
    (tmp_path / "loop").symlink_to(tmp_path / "loop2")
    (tmp_path / "loop2").symlink_to(tmp_path / "loop")
    (tmp_path / "a.txt").write_text("x")
    os.mkfifo(tmp_path / "pipe")
    cases = [("", PathKind.LOG, "is empty"), (tmp_path / "loop", PathKind.LOG, "symbolic link loop"),
             (tmp_path / "a.txt", PathKind.LOG, "is not a .mcap file"), (tmp_path, PathKind.WEIGHTS, "is a folder"),
             (tmp_path / "a.txt", PathKind.LOG_FOLDER, "is a file, not a folder"),
             (tmp_path / "nope", PathKind.STORE, "no such store"),
             (tmp_path / "pipe", PathKind.WEIGHTS, "is a named pipe")]  # fmt: skip
    for value, kind, message in cases:
        with pytest.raises(PathError, match=message):
            check_input(value, "--x", kind)
    assert check_input(tmp_path, "--x", PathKind.RESULTS_FOLDER) == tmp_path.resolve()


def test_a_write_error_names_the_file_being_written(tmp_path):
    with pytest.raises(OSError) as raised, atomic_path(tmp_path / "out.bin"):
        raise OSError(errno.ENOSPC, "No space left on device")
    assert raised.value.filename == str(tmp_path / "out.bin") and not list(tmp_path.iterdir())


def test_bounded_types_come_from_the_configs(capsys):
    seed = bounded(CollectPlan, "seed")
    assert (seed.kind, seed.low, seed.high) == (int, 0, 2**62) and seed("7") == 7
    parser = CommandParser(prog="prog")
    parser.add_argument("--seed", type=seed)
    parser.add_argument("--fps", type=Bounded(float, 0.01, 1000.0))
    for argv, message in ((["--seed", "-1"], "--seed=-1 is invalid; valid range [0, 4611686018427387904]"),
                          (["--seed", "1.5"], "--seed '1.5' is not an integer"),
                          (["--fps", "nan"], "--fps=nan is invalid; it must be a finite number")):  # fmt: skip
        with pytest.raises(SystemExit):
            parser.parse_args(argv)
        assert capsys.readouterr().err == f"prog: error: {message}\n"


def _run(argv: list[str], **kwargs) -> subprocess.CompletedProcess:
    return subprocess.run([PYTHON, *argv], cwd=ROOT, capture_output=True, text=True, timeout=300, **kwargs)


def test_usage_errors_are_one_line_from_the_real_entry_points():
    for argv in (["-m", "flows.collect", "--bogus"], ["-m", "flows.replay"], ["-m", "flows.train", "nosuchstage"],
                 ["-m", "flows.train", "vqvae", "--codes", "codes_default"],  # the PixelCNN's option
                 ["-m", "dynplan.evaluation.results", "--results-dir"]):  # fmt: skip
        proc = _run(argv)
        assert proc.returncode == 2, proc.stderr
        assert len(proc.stderr.strip().splitlines()) == 1 and "error:" in proc.stderr, proc.stderr


def test_an_unreachable_cluster_is_one_line_at_once(capsys):
    start = time.monotonic()
    with pytest.raises(SystemExit):
        flows.collect.main(["--dask-address", "tcp://127.0.0.1:1", "--out", "unused"])
    assert time.monotonic() - start < 10
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--dask-address tcp://127.0.0.1:1: no Dask scheduler answers there" in err[0]


def _interruptible() -> None:
    """In the child: SIGINT as a terminal sends it (a test run in the background inherits it ignored)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


#: A line of `python -X importtime` once the `dynplan` package has loaded: its interrupt handler is in place.
DYNPLAN_LOADED = re.compile(r"\|\s+dynplan$")


def _interrupt(argv: list[str], after: str | None) -> subprocess.CompletedProcess:
    """Start `argv`; send SIGINT once `after` appears on stderr (and a second has passed), or with `after` None once
    the `dynplan` package has loaded and the command's own modules are loading (`-X importtime` says when, however
    loaded the machine: no sleep decides it)."""
    loading = after is None
    command = [PYTHON, *(["-X", "importtime"] if loading else []), *argv]
    proc = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            preexec_fn=_interruptible)  # fmt: skip
    seen = []
    for line in proc.stderr:
        seen.append(line)
        if DYNPLAN_LOADED.search(line.rstrip()) if loading else after in line:
            if not loading:
                time.sleep(1.0)
            break
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=300)
    return subprocess.CompletedProcess(argv, proc.returncode, "", "".join(seen) + err)


#: Commands that run for minutes unless interrupted, and when to interrupt them (None: while they load).
INTERRUPTED = {
    "collect-loading": (["flows.collect", "--out", "{tmp}", "--episodes", "100000"], None),
    "collect-working": (["flows.collect", "--out", "{tmp}", "--episodes", "100000", "--verbose"], "Beginning flow run"),
    "evaluate-loading": (["flows.evaluate", "--results-dir", "{tmp}/results", "--log-dir", "{tmp}/logs"], None),
    "bench-loading": (["dynplan.bench", "world"], None),
}


@pytest.mark.slow
@pytest.mark.parametrize("case", list(INTERRUPTED))
def test_an_interrupt_is_interrupted_and_130(case, tmp_path):
    """While a command loads and while it works: "interrupted", exit status 130, no traceback."""
    argv, after = INTERRUPTED[case]
    proc = _interrupt(["-m", *(a.format(tmp=tmp_path) for a in argv)], after)
    assert proc.returncode == 130, proc.stderr[-2000:]
    assert proc.stderr.strip().splitlines()[-1].startswith(f"python -m {argv[0]}: interrupted")
    assert "Traceback" not in proc.stderr


@pytest.mark.slow
def test_a_full_disk_is_one_line_naming_the_file(tmp_path):
    """`collect` into a 200 kB file system: the last line names the log it could not write, no traceback."""
    disk = tmp_path / "disk"
    disk.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=200k", "tmpfs", str(disk)], capture_output=True).returncode:
        pytest.skip("mounting a small file system needs the privilege to mount")
    try:
        proc = _run(["-m", "flows.collect", "--out", str(disk), "--episodes", "8"])
    finally:
        subprocess.run(["umount", str(disk)], check=False)
    assert proc.returncode == 1, proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert f"{disk}/episode_" in last and "no space left on the device" in last, last


@pytest.mark.parametrize("kind, name", [(PathKind.OUTPUT_GIF, "r.png"), (PathKind.OUTPUT_LOG, "replay.gif"),
                                        (PathKind.OUTPUT_PNG, "shot")])  # fmt: skip
def test_an_output_named_for_another_format_is_refused(tmp_path, kind, name):
    """`--gif r.png` would write a GIF under a PNG's name: refused, naming the suffix it needs."""
    with pytest.raises(PathError, match=rf"--x {tmp_path / name}: is not a \{kind.suffix} name"):
        check_path(tmp_path / name, "--x", kind)
    assert check_path(tmp_path / f"r{kind.suffix.upper()}", "--x", kind) == tmp_path / f"r{kind.suffix.upper()}"


def test_replay_refuses_a_gif_named_png():
    log = "datasets/replays/episode_0001000000.replay-model-default-s5-f0.mcap"  # a log there is (tracked)
    proc = _run(["-m", "flows.replay", log, "--gif", "r.png"])
    assert proc.returncode == 2 and proc.stderr.strip().count("\n") == 0, proc.stderr
    assert "--gif r.png: is not a .gif name" in proc.stderr, proc.stderr
