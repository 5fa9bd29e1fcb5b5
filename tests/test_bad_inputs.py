"""Bad input gets one clear line and exit status 2 before any work, outputs never overwrite inputs, and concurrent
writers into one folder lose nothing (docs/robustness.md lists the cases)."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

import flows.build_datasets
import flows.collect
import flows.evaluate
import flows.replay
import flows.train
from dynplan.data.collect import log_path, record_episode, stale_temporaries
from dynplan.logs import read_episode_log
from dynplan.models.weights import pretrained_path
from dynplan.paths import PACKAGE, PathError, check_output

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """A folder with one recorded log, a file, a foreign Zarr store, a folder of other things, a truncated
    checkpoint."""
    root = tmp_path_factory.mktemp("inputs")
    record_episode(root / "logs", 3)
    (root / "a_file").write_text("not a folder")
    (root / "foreign.zarr").mkdir()
    foreign = {"zarr_format": 3, "node_type": "group", "attributes": {"format": "someone.else"}}
    (root / "foreign.zarr" / "zarr.json").write_text(json.dumps(foreign))
    (root / "things").mkdir()
    (root / "things" / "notes.txt").write_text("hello")
    (root / "truncated.pt").write_bytes(pretrained_path("pixelcnn", "paper").read_bytes()[:1000])
    for name, (vqvae, pixelcnn) in {"cut": ("default", None), "pair": ("paper", "default"),
                                    "kinds": ("default", "vqvae")}.items():  # fmt: skip
        folder = root / name / "default"
        folder.mkdir(parents=True)
        (folder / "vqvae.pt").write_bytes(pretrained_path("vqvae", vqvae).read_bytes())
        prior = pretrained_path("pixelcnn", "default").read_bytes()[:5000] if pixelcnn is None else (
            pretrained_path("vqvae", "default") if pixelcnn == "vqvae" else pretrained_path("pixelcnn", pixelcnn)
        ).read_bytes()  # fmt: skip
        (folder / "pixelcnn.pt").write_bytes(prior)
    return root


#: Imported with the test module, not inside a test: Prefect binds its log handlers to the streams of the moment,
#: and a test's captured streams close after it.
MAINS = {"build_datasets": flows.build_datasets.main, "collect": flows.collect.main, "replay": flows.replay.main,
         "train": flows.train.main, "evaluate": flows.evaluate.main}  # fmt: skip


def _main(module: str):
    return MAINS[module]


CASES = [
    ("collect", ["--out", "{root}/a_file", "--episodes", "1"],
     "--out {root}/a_file: is a file; give the path of a folder"),
    ("build_datasets", ["{root}/logs", "--out", "{root}/a_file"], "--out {root}/a_file: is a file"),
    ("build_datasets", ["{root}/logs", "--out", "{root}/things"], "is a folder but not a Zarr store"),
    ("build_datasets", ["{root}/logs", "--out", "{root}/foreign.zarr"],
     "not a dynplan frames store (format 'someone.else')"),
    ("build_datasets", ["{root}/logs", "--out", "{root}/logs"], "--out {root}/logs: is an input of this command"),
    ("build_datasets", ["{root}/logs", "--out", "{root}"], "holds {root}/logs, which this command reads"),
    ("replay", ["{root}/logs/episode_0000000003.mcap", "--out", "{root}/logs/episode_0000000003.mcap"],
     "--out {root}/logs/episode_0000000003.mcap: is an input of this command"),
    ("replay", ["{root}/logs/episode_0000000003.mcap", "--out", "{root}/r.mcap", "--gif", "{root}/r.mcap"],
     "--gif {root}/r.mcap: is not a .gif name"),  # never the path of --out: a GIF's name ends .gif, a log's .mcap
    ("replay", ["{root}/logs/episode_0000000003.mcap", "--out", "{root}/things"], "--out {root}/things: is a folder"),
    ("replay", ["{root}/logs/episode_0000000003.mcap", "--out", "{root}/a_file/x.mcap"], "is a file, so nothing can"),
    ("replay", ["{root}/logs/episode_0000000003.mcap", "--out", "{root}/r.mcap", "--seed", "-1"],
     "seed=-1 is invalid"),
    ("replay", ["{root}/logs/episode_0000000003.mcap", "--agent-speed", "0.7"],
     "--agent-speed invalid choice: 0.7 (choose from 1.0, 0.5)"),
    ("replay", ["{root}/logs/episode_0000000003.mcap", "--out", "{root}/r.mcap", "--planner", "mid", "--model-dir",
                "{root}/things"], "no world model checkpoints at {root}/things/default/vqvae.pt"),
    ("train", ["vqvae", "--set", "codebook_size=notjson"],
     "--set 'codebook_size=notjson': the value 'notjson' is not JSON"),
    ("train", ["vqvae", "--set", "codebook_size"], "--set 'codebook_size': expected KEY=JSON"),
    ("train", ["pixelcnn", "--init-from", "{root}/truncated.pt"], "{root}/truncated.pt: not a readable checkpoint"),
    ("train", ["pixelcnn", "--init-from", str(pretrained_path("vqvae", "paper"))],
     "holds a 'vqvae' checkpoint, expected 'pixelcnn'"),
    ("train", ["vqvae", "--init-from", "{root}/nowhere.pt"], "--init-from {root}/nowhere.pt: no such checkpoint"),
    ("evaluate", ["--techniques", "samples5", "--model-dir", "{root}/cut"],
     "--model-dir {root}/cut: {root}/cut/default/pixelcnn.pt: not a readable checkpoint"),
    ("evaluate", ["--techniques", "samples5", "--model-dir", "{root}/pair"],
     "{root}/pair/default/vqvae.pt: its configuration is 'paper''s, not 'default''s (it does not match the model "
     "card vqvae-default.json; it is a copy of vqvae-paper.pt)"),
    ("evaluate", ["--techniques", "samples5", "--model-dir", "{root}/kinds"],
     "{root}/kinds/default/pixelcnn.pt: holds a 'vqvae' checkpoint, expected 'pixelcnn'"),
    ("evaluate", ["--techniques", "samples5", "--model-dir", "{root}/things"],
     "no world model checkpoints at {root}/things/default/vqvae.pt"),
    ("build_datasets", ["--verify", "{root}/things"], "--verify {root}/things: no Zarr store there"),
    ("build_datasets", ["--verify", "{root}/foreign.zarr"], "not a dynplan frames store (format 'someone.else')"),
    ("build_datasets", [], "give LOG_DIR, the folder of episode logs (or --verify STORE)"),
]  # fmt: skip


@pytest.mark.parametrize(("module", "argv", "message"), CASES, ids=[f"{c[0]}-{i}" for i, c in enumerate(CASES)])
def test_bad_input_is_one_line_and_exit_2(module, argv, message, inputs, capsys):
    fill = {"root": str(inputs.resolve())}
    with pytest.raises(SystemExit) as stop:
        _main(module)([a.format(**fill) for a in argv])
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert message.format(**fill) in err[-1], err[-1]
    assert "Traceback" not in "\n".join(err)


def test_cuda_on_a_build_without_it_is_named(capsys):
    import torch

    if torch.cuda.is_available():
        pytest.skip("a CUDA device is present")
    with pytest.raises(SystemExit):
        _main("train")(["vqvae", "--device", "cuda"])
    assert "device 'cuda': this torch build sees no CUDA device" in capsys.readouterr().err


def test_check_output_accepts_what_it_should(tmp_path):
    assert check_output(tmp_path / "new" / "deeper" / "x.mcap", "--out") == (tmp_path / "new/deeper/x.mcap").resolve()
    assert check_output(tmp_path, "--out", "folder") == tmp_path.resolve()
    (tmp_path / "old.mcap").write_text("")
    assert check_output(tmp_path / "old.mcap", "--out", inputs=(tmp_path / "other.mcap",))  # an output may be replaced


def test_outputs_stay_out_of_the_package_and_of_the_inputs(tmp_path, capsys):
    """Nothing is written beside the committed weights, and no output folder goes inside a folder the command
    reads (a results page inside the results store, a training run inside its frames store)."""
    for path, kind in ((PACKAGE / "models" / "x", "folder"), (PACKAGE, "folder"), (PACKAGE / "x.mcap", "file")):
        with pytest.raises(PathError, match=rf"^--out .*: is inside the installed package {PACKAGE}; choose a path"):
            check_output(path, "--out", kind)
    (tmp_path / "store").mkdir()
    with pytest.raises(PathError, match=r"^--out .*/store/runs: is inside .*/store, which this command reads; "):
        check_output(tmp_path / "store" / "runs", "--out", "folder", inputs=(tmp_path / "store",))
    with pytest.raises(SystemExit):
        _main("train")(["vqvae", "--out", str(PACKAGE / "models" / "runs")])
    assert f"--out {PACKAGE / 'models' / 'runs'}: is inside the installed package" in capsys.readouterr().err
    assert not (PACKAGE / "models" / "runs").exists()


@pytest.mark.slow
def test_build_datasets_exits_1_and_names_the_logs_that_failed(inputs, tmp_path):
    logs = tmp_path / "logs"
    logs.mkdir()
    good = log_path(inputs / "logs", 3)
    (logs / good.name).write_bytes(good.read_bytes())
    (logs / "broken.mcap").write_bytes(good.read_bytes()[:5000])
    (logs / "folder.mcap").mkdir()
    proc = subprocess.run([sys.executable, "-m", "flows.build_datasets", str(logs), "--out", str(tmp_path / "s.zarr")],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)  # fmt: skip
    assert proc.returncode == 1, proc.stderr[-2000:]
    assert f"skipped {logs / 'folder.mcap'}: not a file" in proc.stderr
    assert proc.stderr.count(str(logs / "broken.mcap")) == 1  # one line a failed log, saying what was wrong
    assert f"skipped: {logs / 'broken.mcap'}: truncated or corrupt: " in proc.stderr
    assert "failed on 1 of its inputs (each skipped above); the rest are in the store" in proc.stderr
    assert "Traceback" not in proc.stderr


@pytest.mark.slow
def test_a_live_writers_temporary_file_survives_another_collection(tmp_path):
    holder = subprocess.Popen([sys.executable, "-c", (
        "import sys, time\nfrom dynplan.files import atomic_path\n"
        f"with atomic_path({str(tmp_path / 'episode_0000000009.mcap')!r}) as tmp:\n"
        "    tmp.write_bytes(b'half'); print(tmp, flush=True); time.sleep(60)\n")],
        stdout=subprocess.PIPE, text=True)  # fmt: skip
    try:
        live = Path(holder.stdout.readline().strip())
        assert live.is_file() and stale_temporaries(tmp_path) == []
        proc = subprocess.run([sys.executable, "-m", "flows.collect", "--episodes", "2", "--out", str(tmp_path)],
                              cwd=ROOT, capture_output=True, text=True, timeout=300)  # fmt: skip
        assert proc.returncode == 0, proc.stderr[-2000:]
        assert live.is_file()  # another writer's file is not ours to remove
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    assert stale_temporaries(tmp_path) == [live]  # its writer is gone: now it is stale


@pytest.mark.slow
def test_two_collections_into_one_folder_both_finish(tmp_path):
    argv = [sys.executable, "-m", "flows.collect", "--episodes", "8", "--seed", "100", "--out", str(tmp_path)]
    env = {**os.environ}
    procs = [subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env)
             for _ in range(2)]  # fmt: skip
    time.sleep(0.1)
    for proc in procs:
        proc.wait(timeout=300)
        assert proc.returncode == 0, proc.stderr.read()[-2000:]
    logs = sorted(tmp_path.glob("episode_*.mcap"))
    assert [read_episode_log(p).seed for p in logs] == list(range(100, 108))
    assert not list(tmp_path.glob(".*.tmp"))


def test_a_live_temporary_file_with_a_suffix_is_not_stale(tmp_path):
    from dynplan.files import atomic_path, stale_temporaries

    with atomic_path(tmp_path / "figure.png", keep_suffix=True) as tmp:
        tmp.write_bytes(b"x")
        assert tmp.name.endswith(".tmp.png") and stale_temporaries(tmp_path) == []
    (tmp_path / ".figure.png.abc123.tmp").write_text("")  # no owner recorded: stale
    assert [p.name for p in stale_temporaries(tmp_path)] == [".figure.png.abc123.tmp"]
