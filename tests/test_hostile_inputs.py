"""A harness that keeps looking for bad input the commands accept. For every command it draws bad values for each
option from the option's own declaration (`Bounded` ranges, path kinds, choices) and damaged copies of each kind of
input file, runs the command in-process as its `python -m` entry point would, and asserts: a non-zero exit, one
line naming the bad thing, no traceback, and no file changed (inputs included). A command that accepts a bad case
reaches its work, which the harness stops before anything runs (`Accepted`).

`DYNPLAN_HARNESS_REPORT=FILE` writes the cases drawn and their outcomes, per class, to FILE (docs/robustness.md).
"""

from __future__ import annotations

import argparse
import io
import json
import os
import re
import shutil
import stat
from contextlib import ExitStack, redirect_stderr, redirect_stdout
from dataclasses import dataclass, field
from pathlib import Path
from unittest import mock

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from prefect.flows import Flow
from zarr.core.metadata.v3 import ArrayV3Metadata

import dynplan.evaluation.results
import flows.bench_pipeline
import flows.build_datasets
import flows.collect
import flows.collect_train_eval
import flows.evaluate
import flows.play
import flows.replay
import flows.serve
import flows.train
import flows.view
from dynplan.cli import CommandParser, run_command
from dynplan.data.build import build_frame_store
from dynplan.data.collect import record_episode
from dynplan.data.store import inspect_for_store
from dynplan.evaluation.store_schema import ManifestSchema, RowSchema
from dynplan.logs.reader import LogError, read_episode_log
from dynplan.models import checkpoint
from dynplan.models.weights import pretrained_path
from tests.hostile import (
    LOG_DAMAGE,
    OUTCOMES,
    bad_values,
    damage_json,
    damage_json_lines,
    damage_log,
    damage_weights,
    tree_state,
)

ROOT = Path(__file__).resolve().parents[1]


class Accepted(BaseException):
    """Raised where a command would start its work: the case was accepted."""


def _accepted(*args, **kwargs):
    raise Accepted


@dataclass(frozen=True)
class Command:
    """A command as the harness runs it: its `main`, a base command line it accepts, and its primary input."""

    main: object
    prog: str
    base: tuple[str, ...]
    input: str | None = None  # for outputs that must not be it, or be in it
    extra: dict = field(default_factory=dict)  # known-bad values of its plain-string options
    exempt: tuple[str, ...] = ()  # options with no bad value to draw (and why, in the table below)
    world: str | None = None  # another world's command (`--world W`, first in `base`): its parser is that world's


_DEVICE = ["gpu", "cuda:x", "", "tpu", "cuda:99", "cpu:0:0"]
_DASK = ["nonsense", "tcp://127.0.0.1:1", "", "tcp://host:99999", "tcp://:8786"]
COMMANDS = {
    "collect": Command(flows.collect.main, "python -m flows.collect", ("--out", "{out}/logs", "--episodes", "1"),
                       None, {"--dask-address": _DASK}),
    "build_datasets": Command(flows.build_datasets.main, "python -m flows.build_datasets",
                              ("{logs}", "--out", "{out}/s.zarr"), "{logs}", {"--dask-address": _DASK}),
    "replay": Command(flows.replay.main, "python -m flows.replay", ("{log}", "--out", "{out}/r.mcap"), "{log}",
                      {"--device": _DEVICE}),
    "train": Command(flows.train.main, "python -m flows.train", ("vqvae", "--store", "{store}", "--out", "{out}/ck"),
                     "{store}", {"--device": _DEVICE, "--set": ["codebook_size", "=1", "codebook_size=notjson",
                                                                "nosuchfield=1", "codebook_size=-5"]},
                     exempt=("--codes",)),
    "evaluate": Command(flows.evaluate.main, "python -m flows.evaluate",
                        ("--techniques", "oracle", "--log-dir", "{out}/el", "--results-dir", "{out}/res",
                         "--episodes", "1", "--run", "probe", "--first-seed", "5"), None,
                        {"--device": _DEVICE, "--dask-address": _DASK,
                         "--run": ["", "../up", "a/b", ".hidden", "x" * 101, "sp ace"]}),
    "play": Command(flows.play.main, "python -m flows.play", ("--no-imagination",), None,
                    {"--script": ["nosuchkey", "up,nosuch", "ctrl+alt", ",".join(["up"] * 40_000)]}),
    "collect_train_eval": Command(flows.collect_train_eval.main, "python -m flows.collect_train_eval",
                                  ("--out", "{out}/cte"), None, {"--dask-address": _DASK}),
    "serve": Command(flows.serve.main, "python -m flows.serve", ("--out", "{out}/srv"), None,
                     {"--dask-address": _DASK}),
    "view": Command(flows.view.main, "python -m flows.view", ("{log}",), "{log}"),
    "bench_pipeline": Command(flows.bench_pipeline.main, "python -m flows.bench_pipeline", ("--out", "{out}/b.json")),
    "collect_minigrid": Command(flows.collect.main, "python -m flows.collect",
                                ("--world", "minigrid", "--out", "{out}/mlogs", "--episodes", "1"), None,
                                {"--dask-address": _DASK}, world="minigrid"),
    "evaluate_minigrid": Command(flows.evaluate.main, "python -m flows.evaluate",
                                 ("--world", "minigrid", "--techniques", "stand_still", "--episodes", "1",
                                  "--results-dir", "{out}/mres", "--run", "probe"), None,
                                 {"--dask-address": _DASK, "--run": ["", "../up", "a/b", "x" * 101]}, world="minigrid"),
    "evaluate_freeway": Command(flows.evaluate.main, "python -m flows.evaluate",
                                ("--world", "freeway", "--techniques", "zero", "--modes", "0", "--episodes", "1",
                                 "--results-dir", "{out}/fres", "--run", "probe"), None,
                                {"--dask-address": _DASK, "--run": ["", "../up", "a/b", "x" * 101]}, world="freeway"),
    "replay_minigrid": Command(flows.replay.main, "python -m flows.replay",
                               ("--world", "minigrid", "{mlog}", "--out", "{out}/m.mcap"), "{mlog}", world="minigrid"),
    "replay_freeway": Command(flows.replay.main, "python -m flows.replay",
                              ("--world", "freeway", "{flog}", "--technique", "zero", "--out", "{out}/f.mcap"),
                              "{flog}", world="freeway"),
    "results": Command(dynplan.evaluation.results.main, "python -m dynplan.evaluation.results",
                       ("--results-dir", "{results}", "--readme", "{readme}", "--docs", "{docs}"), "{results}",
                       {"--readme": ["{folder}", "{devnode}", "{missing}.md", "{loop}", "{fifo}", "{file}"]}),
}  # fmt: skip
#: Why an option has no bad value to draw: `--codes` names a code array only the pixelcnn stage reads.
#: Flags (no value), --help and --debug draw nothing either.


#: The runs of the results store the harness damages (small ones, so that each case is quick).
#: The rows of the committed evaluation kept in the scene's small store: a partly played evaluation.
RESULT_ROWS = 300


@dataclass
class Scene:
    """A folder of good inputs (a log folder, a frames store, weights, a results store, pages) and hostile things
    (a device node, a pipe, a link loop, a dangling link, a file, a folder), each named by a placeholder."""

    root: Path

    def fill(self, text: str, command: Command) -> str:
        names = {"devnode": "hostile/devnode", "fifo": "hostile/fifo", "loop": "hostile/loop", "file": "hostile/a_file",
                 "folder": "hostile/a_folder", "under_file": "hostile/a_file", "missing": "hostile/missing",
                 "dangling": "hostile/dangling", "logs": "inputs/logs", "log": "inputs/logs/episode_0000000003.mcap",
                 "store": "inputs/store.zarr", "results": "inputs/results", "readme": "pages/README.md",
                 "docs": "pages", "models": "inputs/models", "out": "out",
                 "mlog": "inputs/mlogs/episode_0000000001.mcap",
                 "flog": "inputs/flogs/episode_0000000000.mcap"}  # fmt: skip
        values = {k: str(self.root / v) for k, v in names.items()}
        input_path = Path(values[command.input.strip("{}")]) if command.input else self.root / "no-input"
        values |= {"input": str(input_path), "input_dir": str(input_path), "input_root": str(self.root)}
        return re.sub(r"\{(\w+)\}", lambda m: values.get(m.group(1), m.group(0)), text)  # other braces stay


def _hostile_things(folder: Path) -> None:
    folder.mkdir()
    try:
        os.mknod(folder / "devnode", 0o666 | stat.S_IFCHR, os.makedev(1, 3))  # a node like /dev/null's
    except PermissionError:
        (folder / "devnode").symlink_to("/dev/null")
    os.mkfifo(folder / "fifo")
    (folder / "loop").symlink_to(folder / "loop2")
    (folder / "loop2").symlink_to(folder / "loop")
    (folder / "dangling").symlink_to(folder / "nowhere")
    (folder / "a_file").write_text("not what was asked for")
    (folder / "a_folder").mkdir()
    (folder / "a_folder" / "notes.txt").write_text("hello")


@pytest.fixture(autouse=True)
def _a_display(monkeypatch):
    """The play window is patched out: SDL's dummy driver stands for the display `flows.play` checks it has."""
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Scene:
    root = tmp_path_factory.mktemp("hostile")
    _hostile_things(root / "hostile")
    inputs = root / "inputs"
    for seed in (3, 4):
        record_episode(inputs / "logs", seed)
    record_episode(inputs / "mlogs", 1, world_name="minigrid")
    record_episode(inputs / "flogs", 0, world_name="freeway")
    build_frame_store(inputs / "store.zarr", [inspect_for_store(p) for p in sorted((inputs / "logs").glob("*.mcap"))])
    for name in ("vqvae", "pixelcnn"):  # as a pipeline writes them: saved with their weights' digest
        state = torch.load(pretrained_path(name, "default"), map_location="cpu", weights_only=False)
        checkpoint.save(inputs / "models" / "default" / f"{name}.pt", state)
    evaluation = ROOT / "datasets" / "results" / "runs" / "evaluation"
    small = inputs / "results" / "runs" / "evaluation"
    small.mkdir(parents=True)  # a small store (a partly played evaluation), and the pages made from it
    shutil.copy(evaluation / "manifest.json", small)
    rows = (evaluation / "episodes.jsonl").read_text().splitlines(keepends=True)[:RESULT_ROWS]
    (small / "episodes.jsonl").write_text("".join(rows))
    (root / "pages").mkdir()
    shutil.copyfile(ROOT / "README.md", root / "pages" / "README.md")
    scene = Scene(root)
    command = COMMANDS["results"]
    assert invoke(command, [scene.fill(a, command) for a in command.base] + ["--allow-loss"])[0] == 0
    (root / "out").mkdir()
    return scene


def invoke(command: Command, argv: list[str]) -> tuple[int | str, str]:
    """Run `command` in-process on `argv` as its entry point would; (exit status or "accepted", stderr)."""
    err = io.StringIO()
    with ExitStack() as stack:
        stack.enter_context(redirect_stderr(err))
        stack.enter_context(redirect_stdout(io.StringIO()))
        stack.enter_context(mock.patch.object(Flow, "__call__", _accepted))
        for target in (
            "flows.worlds.play_window",
            "flows.serve.serve",
            "flows.bench_pipeline.bench_pipeline",
            "flows.view.install",
        ):
            stack.enter_context(mock.patch(target, _accepted))
        try:
            run_command(command.main, command.prog, argv)
            code: int | str = 0  # it ran to the end
        except SystemExit as stop:
            code = stop.code if isinstance(stop.code, int) else 1
        except Accepted:
            code = "accepted"
    return code, err.getvalue()


def check_refused(code, err: str, names: tuple[str, ...], before: dict, after: dict, what: str,
                  report: bool = False) -> None:  # fmt: skip
    """The case was refused: non-zero exit, one line naming one of `names` (a `report`, as `--verify` gives: one line
    per damaged thing, each naming one of them), no traceback, nothing changed."""
    lines = err.strip().splitlines()
    OUTCOMES[(what, "accepted" if code == "accepted" else "refused")] += 1
    assert code != "accepted" and code != 0, f"accepted: {what}"
    assert "Traceback" not in err, err
    assert len(lines) == 1 or (report and lines), f"{len(lines)} lines: {err}"
    for line in lines[:-1]:
        assert any(name and name in line for name in names), f"names none of {names}: {line}"
    assert "--debug" not in lines[0], f"an unexpected error, not a refusal: {lines[0]}"
    assert any(name and name in lines[0] for name in names), f"names none of {names}: {lines[0]}"
    assert before == after, sorted(set(before.items()) ^ set(after.items()))[:4]


# --- bad option values ---------------------------------------------------------------------------------------


def _parser(command: Command) -> CommandParser:
    """The command's parser, as its `main` builds it."""
    found = []

    def capture(self, args=None, namespace=None):
        found.append(self)
        raise Accepted

    display = mock.patch.dict(os.environ, {"SDL_VIDEODRIVER": "dummy"})  # flows.play asks for a display first
    with mock.patch.object(argparse.ArgumentParser, "parse_args", capture), display, pytest.raises(Accepted):
        command.main(["--world", command.world] if command.world else [])
    return found[0]


def _options() -> list[tuple[str, str]]:
    pairs = []
    for name, command in COMMANDS.items():
        for action in _parser(command)._actions:
            option = action.option_strings[-1] if action.option_strings else action.dest
            if action.nargs != 0 and option not in command.exempt:
                pairs.append((name, option))
    return pairs


OPTIONS = _options()


def _action(command: Command, option: str):
    return next(a for a in _parser(command)._actions if option in (*a.option_strings, a.dest))


def test_every_option_declares_what_it_takes():
    """Every command's parser says a usage error in one line; an option that takes a value declares its type (a
    range, a path kind, choices) or lists known-bad values."""
    plain = [name for name, command in COMMANDS.items() if not isinstance(_parser(command), CommandParser)]
    assert not plain, f"parsers that print a usage block: {plain}"
    undeclared = [f"{name} {option}" for name, option in OPTIONS
                  if bad_values(_action(COMMANDS[name], option), COMMANDS[name].extra) is None]  # fmt: skip
    assert not undeclared, undeclared


def test_every_base_command_line_is_accepted(scene):
    """The base command lines are good, so a refusal below is the drawn value's."""
    for name, command in COMMANDS.items():
        code, err = invoke(command, [scene.fill(a, command) for a in command.base])
        assert code in ("accepted", 0), f"{name}: {err}"


def _with_value(command: Command, action, value: str, scene: Scene) -> list[str]:
    """The base command line with `action` given `value` (replacing the base's own value, if any)."""
    argv = [scene.fill(a, command) for a in command.base]
    if not action.option_strings:  # a positional: the base's first value that is not an option
        index = next((i for i, a in enumerate(argv) if not a.startswith("-")), None)
        return [value, *argv[1:]] if index == 0 else [value, *argv]
    for flag in action.option_strings:
        if flag in argv:
            i = argv.index(flag)
            return [*argv[:i], f"{flag}={value}", *argv[i + 2 :]]
    return [*argv, f"{action.option_strings[-1]}={value}"]


@pytest.mark.parametrize(("name", "option"), OPTIONS, ids=[f"{n}{o}" for n, o in OPTIONS])
@settings(max_examples=8, deadline=None, suppress_health_check=list(HealthCheck), derandomize=False)
@given(data=st.data())
def test_a_bad_option_value_is_refused_in_one_line(name, option, data, scene):
    command = COMMANDS[name]
    action = _action(command, option)
    values = bad_values(action, command.extra)
    if command.input is None:  # no input for an output to collide with
        values = values.filter(lambda v: "{input" not in v)
    raw = data.draw(values, label=option)
    value = scene.fill(raw, command)
    before = tree_state(scene.root)
    code, err = invoke(command, _with_value(command, action, value, scene))
    names = (*action.option_strings, option, f"{action.dest}=", *([value] if value.strip() else []))
    check_refused(code, err, names, before, tree_state(scene.root), f"option:{name}")


# --- damaged input files -------------------------------------------------------------------------------------


def _case_folder(scene: Scene) -> Path:
    folder = scene.root / "case"
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir()
    return folder


def _run_damaged(command: Command, argv: list[str], damaged: Path, scene: Scene, what: str, report: bool = False):
    before = tree_state(scene.root)
    code, err = invoke(command, argv)
    check_refused(code, err, (str(damaged), damaged.name), before, tree_state(scene.root), what, report)


@settings(max_examples=60, deadline=None, suppress_health_check=list(HealthCheck))
@given(damage=LOG_DAMAGE, reader=st.sampled_from(["replay", "play"]))
def test_a_damaged_log_is_refused_in_one_line(damage, reader, scene):
    log = _case_folder(scene) / "episode_0000000003.mcap"
    shutil.copyfile(scene.fill("{log}", COMMANDS["replay"]), log)
    damage_log(log, *damage)
    assume(not _same_log(log, Path(scene.fill("{log}", COMMANDS["replay"]))))
    argv = [str(log), "--out", str(scene.root / "out" / "r.mcap")] if reader == "replay" else ["--log", str(log)]
    _run_damaged(COMMANDS[reader], argv, log, scene, f"log:{damage[0]}")


def _same_log(damaged: Path, original: Path) -> bool:
    """Whether dynplan reads the same episode from both files (a flipped byte in an index the reader does not use
    changes nothing read, so it is no damage to dynplan)."""
    try:
        a = read_episode_log(damaged)
    except LogError:
        return False
    b = read_episode_log(original)
    same = a.metadata == b.metadata and np.array_equal(a.agent_start, b.agent_start)
    return same and np.array_equal(a.frames, b.frames) and np.array_equal(a.goal, b.goal)


def _results_files(scene: Scene) -> list[Path]:
    runs = sorted((scene.root / "inputs" / "results" / "runs").iterdir())
    return [run / name for run in runs for name in ("episodes.jsonl", "manifest.json") if (run / name).is_file()]


@settings(max_examples=60, deadline=None, suppress_health_check=list(HealthCheck))
@given(
    pick=st.floats(0, 1, exclude_max=True),
    how=st.sampled_from(["retype", "drop", "cut", "conflict"]),
    line=st.floats(0, 1, exclude_max=True),
    key=st.floats(0, 1, exclude_max=True),
    wrong=st.integers(0, 50),
)
def test_a_damaged_results_store_is_refused_in_one_line(pick, how, line, key, wrong, scene):
    files = _results_files(scene)
    path = files[int(pick * len(files))]
    pristine = path.read_bytes()
    try:
        if path.suffix == ".jsonl":
            damage_json_lines(path, how, line, key, wrong)
        else:
            damage_json(path, {"conflict": "retype"}.get(how, how), key, wrong)
        assume(how != "drop" or not _still_valid(path))  # a dropped optional field (an older row's) is no damage
        command = COMMANDS["results"]
        argv = [scene.fill(a, command) for a in command.base]
        before = tree_state(scene.root)
        code, err = invoke(command, argv)
        names = (str(path), path.name, scene.fill("{results}", command))  # a row valid but other: the pages' loss
        check_refused(code, err, names, before, tree_state(scene.root), f"results:{how}")
    finally:
        path.write_bytes(pristine)


def _still_valid(path: Path) -> bool:
    """Whether a results file still keeps to the store's schema, line by line (a row) or whole (a manifest)."""
    try:
        if path.suffix == ".jsonl":
            for line in path.read_text().splitlines():
                RowSchema.model_validate(json.loads(line))
        else:
            ManifestSchema.model_validate(json.loads(path.read_text()))
    except ValueError:
        return False
    return True


def _meaning(document: Path) -> object:
    """What Zarr reads from a `zarr.json`: an array's metadata with its defaults filled in (so that dropping a field
    whose default is the value it had changes nothing), or the document itself."""
    try:
        data = json.loads(document.read_text())
        return ArrayV3Metadata.from_dict(data).to_dict() if data.get("node_type") == "array" else data
    except Exception:  # damaged beyond reading: surely changed
        return document.read_bytes()


def _damaged_store(scene: Scene, pick: float, how: str, key: float, wrong: int) -> Path:
    store = _case_folder(scene) / "store.zarr"
    shutil.copytree(scene.fill("{store}", COMMANDS["train"]), store)
    document = sorted(store.rglob("zarr.json"))[int(pick * len(sorted(store.rglob("zarr.json"))))]
    meaning = _meaning(document)
    damage_json(document, how, key, wrong)
    assume(_meaning(document) != meaning)  # a change Zarr cannot see is no damage
    return store


_METADATA = {"pick": st.floats(0, 1, exclude_max=True), "how": st.sampled_from(["retype", "drop", "cut"]),
             "key": st.floats(0, 1, exclude_max=True), "wrong": st.integers(0, 50)}  # fmt: skip


@settings(max_examples=40, deadline=None, suppress_health_check=list(HealthCheck))
@given(**_METADATA)
def test_a_store_with_damaged_metadata_is_refused_by_its_readers(pick, how, key, wrong, scene):
    store = _damaged_store(scene, pick, how, key, wrong)
    command = COMMANDS["train"]
    argv = ["vqvae", "--store", str(store), "--out", scene.fill("{out}/ck", command)]
    _run_damaged(command, argv, store, scene, f"metadata:{how}")


@settings(max_examples=30, deadline=None, suppress_health_check=list(HealthCheck))
@given(**_METADATA)
def test_verify_reports_damaged_metadata_and_repairs_only_what_the_format_determines(pick, how, key, wrong, scene):
    """Without logs, `--verify` refuses a store it cannot read (exit 2), names each damaged thing in a line of its
    own and exits 1, or repairs what the format alone determines (the consolidated copy, format attributes) and
    exits 0, leaving a store that verifies intact."""
    store = _damaged_store(scene, pick, how, key, wrong)
    command = COMMANDS["build_datasets"]
    code, err = invoke(command, ["--verify", str(store)])
    lines = err.strip().splitlines()
    OUTCOMES[(f"verify:{how}", "reported" if code else "repaired")] += 1
    assert code in (0, 1, 2) and "Traceback" not in err, err
    assert all(str(store) in line for line in lines), err
    if code == 0:
        assert invoke(command, ["--verify", str(store)]) == (0, "")


def _reads_the_same(damaged: Path, original: Path) -> bool:
    """Whether torch reads the same checkpoint from both files (a flipped byte in a field of the zip archive that
    torch does not read changes nothing read, so it is no damage)."""
    try:
        a = torch.load(damaged, map_location="cpu", weights_only=False)
    except Exception:
        return False
    b = torch.load(original, map_location="cpu", weights_only=False)
    same = (
        a.keys() == b.keys() and all(k == "model" or a[k] == b[k] for k in a) and a["model"].keys() == b["model"].keys()
    )
    return same and all(torch.equal(a["model"][n], b["model"][n]) for n in b["model"])


_WEIGHT_DAMAGE = st.sampled_from(["truncate", "flip", "reshape", "nan", "other"])


@settings(max_examples=40, deadline=None, suppress_health_check=list(HealthCheck))
@given(
    how=_WEIGHT_DAMAGE,
    where=st.floats(0, 1, exclude_max=True),
    stage=st.sampled_from(["vqvae", "pixelcnn"]),
    reader=st.sampled_from(["evaluate", "train"]),
)
def test_damaged_weights_are_refused_in_one_line(how, where, stage, reader, scene):
    models = _case_folder(scene) / "models"
    shutil.copytree(scene.root / "inputs" / "models", models)
    weights = models / "default" / f"{stage}.pt"
    damage_weights(weights, how, where, pretrained_path(stage, "paper"))
    assume(not _reads_the_same(weights, scene.root / "inputs" / "models" / "default" / f"{stage}.pt"))
    command = COMMANDS[reader]
    argv = [scene.fill(a, command) for a in command.base]
    if reader == "evaluate":
        argv = [a if a != "oracle" else "samples5" for a in argv] + ["--model-dir", str(models)]
    else:
        argv = [stage, *argv[1:], "--init-from", str(weights)]
    _run_damaged(command, argv, weights, scene, f"weights:{how}")
