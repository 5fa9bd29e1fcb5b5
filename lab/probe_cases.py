"""The cases of `lab.probe_inputs`, by class: each a command line (or an API call) on the probe's scene with one
thing made bad, and what its refusal must name."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "dynplan"


@dataclass
class Case:
    """One case: its class, what it is, the command's module and arguments (placeholders `{name}` filled from the
    scene), what its line must name (any of), how to prepare it (on the case's folder) and how it is run."""

    cls: int
    what: str
    module: str = ""
    argv: list[str] = field(default_factory=list)
    names: tuple[str, ...] = ()
    prepare: Callable[[Path], None] | None = None
    env: dict[str, str] | None = None  # run as a subprocess with these variables
    call: Callable[[Path], object] | None = None  # an API call instead of a command
    expect: str = "refused"  # or "ok"
    interrupt_after: float | None = None  # subprocess: SIGINT after this many seconds
    real: bool = False  # run its flows (a check inside them is the one judged), not stop them
    report: bool = False  # a line per bad input (each naming it), then a summary, as --verify and builds give


# --- helpers: copies of the scene's inputs, edited -------------------------------------------------------------


def _copy(name: str) -> Callable[[Path], Path]:
    def copy(folder: Path) -> Path:
        scene = folder.parent / "scene"
        source, target = scene / name, folder / name
        (shutil.copytree if source.is_dir() else shutil.copy)(source, target)
        return target

    return copy


def _pages(folder: Path) -> None:
    shutil.copytree(folder.parent / "scene" / "pages", folder / "out" / "pages")


def _zarr_edit(array: str, index: tuple, value) -> Callable[[Path], None]:
    def edit(folder: Path) -> None:
        import zarr

        _copy("store.zarr")(folder)
        zarr.open_array(folder / "store.zarr" / array, mode="r+")[index] = value

    return edit


def _file_edit(relative: str, change: Callable[[bytes], bytes | None]) -> Callable[[Path], None]:
    def edit(folder: Path) -> None:
        _copy("store.zarr")(folder)
        path = folder / "store.zarr" / relative
        new = change(path.read_bytes())
        if new is None:
            path.unlink()
        else:
            path.write_bytes(new)

    return edit


def _json_edit(relative: str, change: Callable[[dict], None]) -> Callable[[Path], None]:
    def edit(folder: Path) -> None:
        _copy("store.zarr")(folder)
        path = folder / "store.zarr" / relative
        data = json.loads(path.read_text())
        change(data)
        path.write_text(json.dumps(data))

    return edit


def _row_edit(store: str, change: Callable[[list[str]], list[str]], run: str = "evaluation") -> Callable:
    def edit(folder: Path) -> None:
        _copy(store)(folder)
        _pages(folder)
        path = folder / store / "runs" / run / "episodes.jsonl"
        path.write_text("".join(change(path.read_text().splitlines(keepends=True))))

    return edit


def _field(line: int, key: str, value=None, drop: bool = False) -> Callable[[list[str]], list[str]]:
    def change(lines: list[str]) -> list[str]:
        row = json.loads(lines[line - 1])
        if drop:
            row.pop(key)
        else:
            row[key] = value
        lines[line - 1] = json.dumps(row, separators=(",", ":")) + "\n"
        return lines

    return change


def _manifest_edit(store: str, change: Callable[[dict], None], run: str = "evaluation") -> Callable:
    def edit(folder: Path) -> None:
        _copy(store)(folder)
        _pages(folder)
        path = folder / store / "runs" / run / "manifest.json"
        data = json.loads(path.read_text())
        change(data)
        path.write_text(json.dumps(data, indent=1) + "\n")

    return edit


def _set(key, value):
    def change(data: dict) -> None:
        data[key] = value

    return change


# --- class 1: store contents -------------------------------------------------------------------------------------

STORE_DAMAGE = {
    "a frame pixel of 255": _zarr_edit("frames", (0, 10, 5, 5), 255),
    "a frame pixel of 7 (between the palette's)": _zarr_edit("frames", (1, 200, 40, 3), 7),
    "a goal of NaN": _zarr_edit("goal", (0, 5, 0), float("nan")),
    "a goal off the frame": _zarr_edit("goal", (1, 7), (999.0, -5.0)),
    "a seed outside the world's": _zarr_edit("seed", (0,), 2**62 + 5),
    "a negative seed": _zarr_edit("seed", (1,), -3),
    "a frames chunk removed": _file_edit("frames/c/1/0/0/0", lambda b: None),
    "the goal chunk removed": _file_edit("goal/c/0/0/0", lambda b: None),
    "the seed chunk removed": _file_edit("seed/c/0", lambda b: None),
    "a frames chunk cut short": _file_edit("frames/c/0/0/0/0", lambda b: b[: len(b) // 2]),
    "a frames chunk zeroed": _file_edit("frames/c/0/0/0/0", lambda b: bytes(len(b))),
    "a frames chunk with a flipped byte": _file_edit(
        "frames/c/1/0/0/0", lambda b: b[:100] + bytes([b[100] ^ 1]) + b[101:]
    ),
    "another episode's frames chunk": lambda f: (
        _copy("store.zarr")(f),
        shutil.copy(f / "store.zarr/frames/c/0/0/0/0", f / "store.zarr/frames/c/1/0/0/0"),
    ),
    "the group's metadata removed": _file_edit("zarr.json", lambda b: None),
    "frames of another shape in the metadata": _json_edit(
        "frames/zarr.json", lambda d: d.update(shape=[2, 407, 48, 40])
    ),
    "frames of another dtype in the metadata": _json_edit("frames/zarr.json", lambda d: d.update(data_type="int16")),
    "more episodes than the arrays hold": _json_edit("zarr.json", lambda d: d["attributes"].update(episodes=5)),
    "the world named freeway": _json_edit("zarr.json", lambda d: d["attributes"].update(world="freeway")),
    "episodes as a string": _json_edit("zarr.json", lambda d: d["attributes"].update(episodes="2")),
}
_VERIFY = ["--verify", "{case}/store.zarr"]
_TRAIN = ["vqvae", "--store", "{case}/store.zarr", "--out", "{out}/ck", "--epochs", "1", "--steps-per-epoch", "1"]


def store_cases() -> list[Case]:
    out = []
    for what, prepare in STORE_DAMAGE.items():
        unread = "goal" in what  # a VQ-VAE trains on the frames, split by the seeds: the goals are --verify's
        out.append(Case(1, f"--verify: {what}", "flows.build_datasets", _VERIFY, ("store.zarr",), prepare,
                        report=True))  # fmt: skip
        expect = "ok" if unread else "refused"
        out.append(Case(1, f"train: {what}", "flows.train", _TRAIN, ("store.zarr",), prepare, real=True, expect=expect))
    out.append(
        Case(1, "--verify: an intact store", "flows.build_datasets", _VERIFY, (), _copy("store.zarr"), expect="ok")
    )
    return out


# --- class 2: result rows ------------------------------------------------------------------------------------------

ROAD_ROWS = {
    "an extra field": _field(5, "temperature", 0.5),
    "a seed outside the manifest": _field(5, "seed", 12),
    "other playouts": _field(5, "playouts", 50),
    "steps of 10**30": _field(5, "steps", 10**30),
    "steps as a string": _field(5, "steps", "abc"),
    "steps as a float": _field(5, "steps", 12.0),
    "outcome 'win'": _field(5, "outcome", "win"),
    "agent speed 0": _field(5, "agent_speed", 0),
    "agent speed as a string": _field(5, "agent_speed", "1"),
    "rollout steps 0": _field(5, "rollout_steps", 0),
    "an empty technique": _field(5, "technique", ""),
    "wall time -1": _field(5, "wall_s", -1),
    "an empty log checksum": _field(5, "log_sha256", ""),
    "code version as a number": _field(5, "code_version", 5),
    "world-model checksum null": _field(5, "world_model_sha256", None),
    "occupancy 1.0": _field(5, "occupancy", 1.0),
    "margin 5": _field(5, "margin", 5),
    "no outcome": _field(5, "outcome", drop=True),
    "a decision time of -1": _field(5, "decision_ms", [-1.0]),
    "a nested setting": _field(5, "span", {"a": 1}),
    "a second result for a case": lambda lines: [*lines, _other_outcome(lines[4])],
    "a line cut in the middle of the file": lambda lines: [*lines[:4], lines[4][:40] + "\n", *lines[5:]],
    "a JSON array line": lambda lines: [*lines[:4], "[1, 2]\n", *lines[5:]],
    "a NUL line": lambda lines: [*lines[:4], "\0\0\0\n", *lines[5:]],
    "the rows of the first seed gone": lambda lines: [x for x in lines if '"seed":1000013,' not in x],
}


def _other_outcome(line: str) -> str:
    row = json.loads(line)
    return json.dumps({**row, "outcome": "goal" if row["outcome"] != "goal" else "death"}) + "\n"


ROAD_MANIFESTS = {
    "playouts as a string": _set("playouts", "100"),
    "another role": _set("role", "final"),
    "a seed dropped from the list": lambda m: m["episode_seeds"].remove(1000013),
    "the model's entry gone": lambda m: m["world_models"].clear(),
    "another name": _set("name", "other"),
    "another format": _set("format", "dynplan-run/9"),
    "an unknown world": _set("world", "nosuch-v1"),
    "no invocations": lambda m: m.pop("invocations"),
    "a caution margin of 9": lambda m: [
        e.setdefault("caution", {}).update(margin=9) for e in m["world_models"].values()
    ],
}
#: What an evaluation resumes from rather than refuses: rows gone or stale are played again, a model's entry is
#: written again by the run's next invocation.
_EVALUATE_RESUMES = ("row: an extra field", "row: the rows of the first seed gone", "manifest: the model's entry gone")
_PAGES = ["--results-dir", "{case}/results", "--docs", "{out}/pages", "--readme", "{out}/pages/README.md"]
_EVALUATE = ["--results-dir", "{case}/results", "--log-dir", "{out}/el", "--techniques", "oracle", "--episodes", "1"]


def _other_file(store: str, name: str, content: str | None) -> Callable[[Path], None]:
    def edit(folder: Path) -> None:
        _copy(store)(folder)
        _pages(folder)
        path = folder / store / "runs" / "evaluation" / name
        if content is None:
            path.unlink()
            path.mkdir()
        else:
            path.write_text(content)

    return edit


def road_result_cases() -> list[Case]:
    out = []
    damage = {f"row: {k}": _row_edit("results", v) for k, v in ROAD_ROWS.items()}
    damage |= {f"manifest: {k}": _manifest_edit("results", v) for k, v in ROAD_MANIFESTS.items()}
    damage |= {"manifest: empty": _other_file("results", "manifest.json", ""),
               "manifest: a folder": _other_file("results", "manifest.json", None),
               "manifest: gone": lambda f: (_copy("results")(f), _pages(f),
                                            (f / "results/runs/evaluation/manifest.json").unlink())}  # fmt: skip
    for what, prepare in damage.items():
        names = ("episodes.jsonl", "manifest.json", "runs/evaluation", "case/results")  # a loss names the store
        out.append(Case(2, f"results page: {what}", "dynplan.evaluation.results", _PAGES, names, prepare))
        if what not in _EVALUATE_RESUMES:
            out.append(Case(2, f"evaluate: {what}", "flows.evaluate", _EVALUATE, names, prepare))
    return out


FREEWAY_ROWS = {
    "score 'abc'": _field(2, "score", "abc"),
    "score 1e9": _field(2, "score", 1e9),
    "score 2.5": _field(2, "score", 2.5),
    "steps that its actions do not hold": _field(2, "steps", 100),
    "mode 9": _field(2, "mode", 9),
    "technique 'x'": _field(2, "technique", "x"),
    "learned without its model": _field(2, "model", None),
    "actions 'Q5'": _field(2, "actions", "Q5"),
    "NOOP start 99": _field(2, "noop_start", 99),
    "knocks -1": _field(2, "knocks", -1),
    "an extra field": _field(2, "note", "hand-copied"),
    "decision ms 'fast'": _field(2, "decision_ms", "fast"),
    "episode 5000": _field(2, "episode", 5000),
    "a score its actions do not make": _field(2, "score", 3.0),
    "a second result for a case": lambda lines: [*lines, lines[1].replace('"knocks":0', '"knocks":1')],
}
MINIGRID_ROWS = {
    "outcome 'win'": _field(2, "outcome", "win"),
    "steps 'abc'": _field(2, "steps", "abc"),
    "steps its actions do not hold": _field(2, "steps", 5),
    "actions 'Z3'": _field(2, "actions", "Z3"),
    "oracle with a model": _field(2, "model", "minigrid"),
    "a negative seed": _field(2, "seed", -1),
    "an outcome its actions do not reach": _field(2, "outcome", "death"),
    "decision ms NaN": lambda lines: [
        lines[0],
        lines[1].replace('"decision_ms":', '"decision_ms":NaN,"x":'),
        *lines[2:],
    ],
}


def world_result_cases() -> list[Case]:
    out = []
    check = ["--world", "freeway", "--results-dir", "{case}/fresults", "--check"]
    for what, change in FREEWAY_ROWS.items():
        out.append(Case(2, f"freeway --check: {what}", "flows.evaluate", check, ("episodes.jsonl",),
                        _row_edit("fresults", change)))  # fmt: skip
    out.append(Case(2, "freeway manifest: frameskip 5", "flows.evaluate", check, ("manifest.json",),
                    _manifest_edit("fresults", lambda m: m["settings"].update(frameskip=5))))  # fmt: skip
    out.append(Case(2, "freeway manifest: world freeway-v9", "flows.evaluate", check, ("manifest.json",),
                    _manifest_edit("fresults", _set("world", "freeway-v9"))))  # fmt: skip
    check = ["--world", "minigrid", "--results-dir", "{case}/mresults", "--check"]
    for what, change in MINIGRID_ROWS.items():
        out.append(Case(2, f"minigrid --check: {what}", "flows.evaluate", check, ("episodes.jsonl",),
                        _row_edit("mresults", change)))  # fmt: skip
    return out


# --- class 4: the world at every entrance ---------------------------------------------------------------------------

_ML, _FL, _RL = (
    "{scene}/mlogs/episode_0000000001.mcap",
    "{scene}/flogs/episode_0000000000.mcap",
    "{scene}/logs/episode_0000000003.mcap",
)


WORLD_ROWS = [
    ("road replay of a MiniGrid log", "flows.replay", [_ML, "--out", "{out}/r.mcap"], ("minigrid",)),
    ("road replay of a Freeway log", "flows.replay", [_FL, "--out", "{out}/r.mcap"], ("freeway",)),
    ("road play of a MiniGrid log", "flows.play", ["--log", _ML, "--no-imagination"], ("minigrid",)),
    ("road play of a Freeway log", "flows.play", ["--log", _FL, "--no-imagination"], ("freeway",)),
    (
        "MiniGrid replay of a road log",
        "flows.replay",
        ["--world", "minigrid", _RL, "--out", "{out}/r.mcap"],
        ("road",),
    ),
    (
        "MiniGrid replay of a Freeway log",
        "flows.replay",
        ["--world", "minigrid", _FL, "--out", "{out}/r.mcap"],
        ("freeway",),
    ),
    (
        "Freeway replay of a road log",
        "flows.replay",
        ["--world", "freeway", _RL, "--out", "{out}/r.mcap"],
        ("road",),
    ),
    (
        "Freeway replay of a MiniGrid log",
        "flows.replay",
        ["--world", "freeway", _ML, "--out", "{out}/r.mcap"],
        ("minigrid",),
    ),
    (
        "a Freeway store of road logs",
        "flows.build_datasets",
        ["{scene}/logs", "--world", "freeway", "--out", "{out}/f.zarr"],
        ("road", "freeway"),
    ),
    (
        "a road store of MiniGrid logs",
        "flows.build_datasets",
        ["{scene}/mlogs", "--out", "{out}/m.zarr"],
        ("minigrid",),
    ),
    (
        "train --world minigrid on a road store",
        "flows.train",
        ["vqvae", "--world", "minigrid", "--store", "{scene}/store.zarr", "--out", "{out}/ck"],
        ("road",),
    ),
    (
        "train --model minigrid on a road store",
        "flows.train",
        ["vqvae", "--model", "minigrid", "--store", "{scene}/store.zarr", "--out", "{out}/ck"],
        ("road",),
    ),
    (
        "train --model freeway on a road store",
        "flows.train",
        ["vqvae", "--model", "freeway", "--store", "{scene}/store.zarr", "--out", "{out}/ck"],
        ("road",),
    ),
    (
        "MiniGrid evaluate with road weights",
        "flows.evaluate",
        [
            "--world",
            "minigrid",
            "--techniques",
            "learned10",
            "--episodes",
            "1",
            "--results-dir",
            "{out}/m",
            "--model-dir",
            "{scene}/models",
        ],
        ("models",),
    ),
    (
        "Freeway evaluate with road weights",
        "flows.evaluate",
        [
            "--world",
            "freeway",
            "--techniques",
            "learned",
            "--modes",
            "0",
            "--episodes",
            "1",
            "--results-dir",
            "{out}/f",
            "--model-dir",
            "{scene}/models/default",
        ],
        ("models",),
    ),
    (
        "--verify --world freeway of a road store",
        "flows.build_datasets",
        ["--verify", "{scene}/store.zarr", "--world", "freeway"],
        ("road",),
    ),
    (
        "road evaluate with Freeway's weights",
        "flows.evaluate",
        [
            "--techniques",
            "samples5",
            "--models",
            "default",
            "--episodes",
            "1",
            "--log-dir",
            "{out}/el",
            "--results-dir",
            "{out}/r",
            "--model-dir",
            "{scene}/fmodels",
        ],
        ("fmodels",),
    ),
]


def world_cases() -> list[Case]:
    out = [Case(4, what, module, argv, names) for what, module, argv, names in WORLD_ROWS]
    out[-1].prepare = _freeway_models
    for case in out:
        if case.module == "flows.build_datasets" and "--verify" not in case.argv:
            case.real, case.report = True, True  # each log is refused by name, the rest built
    return out


def _freeway_models(folder: Path) -> None:
    scene = folder.parent / "scene"
    target = scene / "fmodels" / "default"
    if not target.exists():
        target.mkdir(parents=True)
        for stage in ("vqvae", "pixelcnn"):
            shutil.copy(PACKAGE / "worlds" / "freeway" / "weights" / f"{stage}-freeway.pt", target / f"{stage}.pt")


# --- class 5: strict types -----------------------------------------------------------------------------------------

_SETS = ["codebook_size=true", 'codebook_size="8"', "codebook_size=8.5", "learning_rate=true", 'learning_rate="1e-3"',
         "learning_rate=null", "grid=[6]", "name=5", "beta=NaN", "beta=Infinity", "codebook_size=[8]",
         'codebook_size={"a":1}', "codebook_size=-1", "learning_rate=-Infinity"]  # fmt: skip


def type_cases() -> list[Case]:
    out = [Case(5, f"--set {s}", "flows.train", ["vqvae", "--store", "{scene}/store.zarr", "--out", "{out}/ck",
                                                  "--set", s], (s.split("=")[0],)) for s in _SETS]  # fmt: skip
    calls = {
        "generate_world(seed=True)": (lambda f: _gw(True), ("seed",)),
        "generate_world(seed='5')": (lambda f: _gw("5"), ("seed",)),
        "generate_world(seed=-1)": (lambda f: _gw(-1), ("seed",)),
        "generate_world(seed=2**64)": (lambda f: _gw(2**64), ("seed",)),
        "generate_world(seed=3.5)": (lambda f: _gw(3.5), ("seed",)),
        "RoadConfig(level='6')": (lambda f: _config("dynplan.env", "RoadConfig", level="6"), ("level",)),
        "RoadConfig(level=True)": (lambda f: _config("dynplan.env", "RoadConfig", level=True), ("level",)),
        "AgentSpec(playouts=1.5)": (
            lambda f: _config("dynplan.evaluation.agent", "AgentSpec", playouts=1.5),
            ("playouts",),
        ),
        "AgentSpec(technique=5)": (
            lambda f: _config("dynplan.evaluation.agent", "AgentSpec", technique=5),
            ("technique",),
        ),
        "TrainBudget(epochs=True)": (
            lambda f: _config("dynplan.training.budget", "TrainBudget", epochs=True),
            ("epochs",),
        ),
        "TrainBudget(max_minutes=nan)": (
            lambda f: _config("dynplan.training.budget", "TrainBudget", max_minutes=float("nan")),
            ("max_minutes",),
        ),
        "record_episode(seed='3')": (lambda f: _record(f, "3"), ("seed",)),
        "record_episode(seed=None)": (lambda f: _record(f, None), ("seed",)),
        "lane_frame(float frames)": (lambda f: _freeway("lane_frame", np.zeros((210, 160, 3), float)), ("screen",)),
        "lane_frame(a list)": (lambda f: _freeway("lane_frame", [[0]]), ("screen",)),
        "plan_episode(world='x')": (lambda f: _plan("x"), ("world",)),
        "plan_episode(spec=3)": (lambda f: _plan(5, agent=3), ("spec",)),
    }
    out += [Case(5, what, call=call, names=names) for what, (call, names) in calls.items()]
    ok = {
        "generate_world(seed=np.int64(3))": lambda f: _gw(np.int64(3)),
        "record_episode(seed=np.int32(2))": lambda f: _record(f, np.int32(2)),
        "RoadConfig(level=6.0)": lambda f: _config("dynplan.env", "RoadConfig", level=6.0),
    }
    out += [Case(5, what, call=call, expect="ok") for what, call in ok.items()]
    return out


def _gw(seed):
    from dynplan.env import RoadConfig, generate_world

    return generate_world(RoadConfig(), seed, n_frames=20)


def _config(module: str, name: str, **fields):
    import importlib

    return getattr(importlib.import_module(module), name)(**fields)


def _record(folder: Path, seed):
    from dynplan.data.collect import record_episode

    return record_episode(folder / "out" / "logs", seed, n_frames=20)


def _freeway(name: str, *args):
    import importlib

    return getattr(importlib.import_module("dynplan.worlds.freeway.game"), name)(*args)


def _plan(world, agent=None):
    from dynplan.evaluation.protocol import plan_episode

    return plan_episode(world, agent)


# --- class 6: the environment ----------------------------------------------------------------------------------------

_COLLECT = ["--out", "{out}/logs", "--episodes", "1", "--seed", "40"]


def environment_cases() -> list[Case]:
    envs = {
        "PREFECT_API_URL not a URL": ({"PREFECT_API_URL": "not a url"}, ("PREFECT_API_URL",)),
        "PREFECT_API_URL ftp": ({"PREFECT_API_URL": "ftp://127.0.0.1/api"}, ("PREFECT_API_URL",)),
        "PREFECT_API_URL where nothing answers": ({"PREFECT_API_URL": "http://127.0.0.1:9/api"}, ("PREFECT_API_URL",)),
        "PREFECT_API_URL of no host": ({"PREFECT_API_URL": "http://no-such-host.invalid/api"}, ("PREFECT_API_URL",)),
        "PREFECT_HOME under a file": (
            {"PREFECT_API_URL": "", "PREFECT_HOME": "/etc/hostname/prefect"},
            ("PREFECT_HOME",),
        ),
        "PREFECT_LOGGING_LEVEL=LOUD": ({"PREFECT_LOGGING_LEVEL": "LOUD"}, ("PREFECT_LOGGING_LEVEL",)),
        "PREFECT_API_REQUEST_TIMEOUT=abc": ({"PREFECT_API_REQUEST_TIMEOUT": "abc"}, ("PREFECT_API_REQUEST_TIMEOUT",)),
        "PREFECT_SERVER_API_PORT=abc": (
            {"PREFECT_API_URL": "", "PREFECT_SERVER_API_PORT": "abc"},
            ("PREFECT_SERVER_API_PORT",),
        ),
        "HOME under a file, no PREFECT_HOME": (
            {"PREFECT_API_URL": "", "PREFECT_HOME": "", "HOME": "/etc/hostname"},
            ("HOME",),
        ),
        "DYNPLAN_DASK_ADDRESS nonsense": ({"DYNPLAN_DASK_ADDRESS": "nonsense"}, ("DYNPLAN_DASK_ADDRESS", "nonsense")),
    }
    return [Case(6, what, "flows.collect", _COLLECT, names, env=env) for what, (env, names) in envs.items()]


# --- class 7: outputs confined ---------------------------------------------------------------------------------------


OUTPUT_ROWS = [
    (
        "train --out inside the package",
        "flows.train",
        ["vqvae", "--store", "{scene}/store.zarr", "--out", "{package}/models/runs"],
        ("--out",),
    ),
    (
        "collect --out inside the package",
        "flows.collect",
        ["--out", "{package}/logs", "--episodes", "1"],
        ("--out",),
    ),
    (
        "build --out inside the package",
        "flows.build_datasets",
        ["{scene}/logs", "--out", "{package}/s.zarr"],
        ("--out",),
    ),
    ("replay --out inside the package", "flows.replay", [_RL, "--out", "{package}/r.mcap"], ("--out",)),
    (
        "replay --gif inside the package",
        "flows.replay",
        [_RL, "--out", "{out}/r.mcap", "--gif", "{package}/r.gif"],
        ("--gif",),
    ),
    (
        "results --docs inside the store",
        "dynplan.evaluation.results",
        ["--results-dir", "{scene}/results", "--docs", "{scene}/results/runs", "--readme", ""],
        ("--docs",),
    ),
    (
        "results --docs inside the package",
        "dynplan.evaluation.results",
        ["--results-dir", "{scene}/results", "--docs", "{package}", "--readme", ""],
        ("--docs",),
    ),
    (
        "results --readme inside the store",
        "dynplan.evaluation.results",
        ["--results-dir", "{scene}/results", "--docs", "{out}", "--readme", "{scene}/results/R.md"],
        ("--readme",),
    ),
    (
        "evaluate --results-dir inside --log-dir",
        "flows.evaluate",
        ["--log-dir", "{out}/el", "--results-dir", "{out}/el/res", "--episodes", "1"],
        ("--results-dir",),
    ),
    (
        "evaluate --log-dir inside the package",
        "flows.evaluate",
        ["--log-dir", "{package}/el", "--results-dir", "{out}/res", "--episodes", "1"],
        ("--log-dir",),
    ),
    ("pipeline --out inside the package", "flows.collect_train_eval", ["--out", "{package}/quick"], ("--out",)),
    (
        "train --tensorboard inside the store",
        "flows.train",
        ["vqvae", "--store", "{scene}/store.zarr", "--out", "{out}/ck", "--tensorboard", "{scene}/store.zarr/tb"],
        ("--tensorboard",),
    ),
    (
        "build --out inside its log folder",
        "flows.build_datasets",
        ["{scene}/logs", "--out", "{scene}/logs/s.zarr"],
        ("--out",),
    ),
    (
        "view --screenshot inside the package",
        "flows.view",
        [_RL, "--screenshot", "{package}/s.png"],
        ("--screenshot",),
    ),
    (
        "freeway evaluate --results-dir inside the package",
        "flows.evaluate",
        ["--world", "freeway", "--results-dir", "{package}/fr", "--episodes", "1", "--modes", "0"],
        ("--results-dir",),
    ),
    (
        "minigrid evaluate --results-dir inside the package",
        "flows.evaluate",
        ["--world", "minigrid", "--results-dir", "{package}/mr", "--episodes", "1"],
        ("--results-dir",),
    ),
]


def output_cases() -> list[Case]:
    return [Case(7, what, module, argv, names) for what, module, argv, names in OUTPUT_ROWS]


# --- class 8: interrupts and limits --------------------------------------------------------------------------------


def _finished_run(folder: Path) -> None:
    import torch

    from dynplan.models.registry import world_model_spec
    from dynplan.training.budget import TrainBudget
    from dynplan.training.runs import vqvae_run_dir

    config = world_model_spec("default").tokenizer.model_dump()
    run = vqvae_run_dir(str(folder.parent / "scene" / "store.zarr"), str(folder / "out" / "ck"), config,
                        TrainBudget(epochs=2).model_dump())  # fmt: skip
    run.mkdir(parents=True)
    torch.save({"kind": "vqvae", "epoch": 3}, run / "vqvae.pt")


def limit_cases() -> list[Case]:
    train = ["vqvae", "--store", "{scene}/store.zarr", "--out", "{out}/ck"]
    rows = [
        ("--epochs 2 of a finished 3-epoch run", "flows.train", [*train, "--epochs", "2"], ("--epochs",)),
        (
            "--script of 40,000 keys",
            "flows.play",
            ["--no-imagination", "--script", ",".join(["up"] * 40_000)],
            ("--script",),
        ),
        (
            "--script of 10,001 keys",
            "flows.play",
            ["--no-imagination", "--script", ",".join(["up"] * 10_001)],
            ("--script",),
        ),
        ("--codes with vqvae", "flows.train", [*train, "--codes", "codes_x"], ("--codes",)),
        ("replay --gif r.png", "flows.replay", [_RL, "--out", "{out}/r.mcap", "--gif", "{out}/r.png"], ("--gif",)),
        ("--episodes 10**7 + 1", "flows.collect", ["--out", "{out}/logs", "--episodes", "10000001"], ("--episodes",)),
        ("--workers 257", "flows.evaluate", ["--world", "minigrid", "--workers", "257"], ("--workers",)),
        ("--batch 0", "flows.evaluate", ["--world", "freeway", "--batch", "0"], ("--batch",)),
        (
            "--set name of 1,000 characters",
            "flows.train",
            [*train, "--set", 'name="' + "x" * 1000 + '"'],
            ("--set", "name"),
        ),
        (
            "--set of 10,000 keys",
            "flows.train",
            [*train, "--set", *[f"k{i}=1" for i in range(10_000)]],
            ("--set", "k0"),
        ),
        ("--first-seed 2**70", "flows.evaluate", ["--first-seed", str(2**70), "--run", "x"], ("--first-seed",)),
    ]
    out = [Case(8, what, module, argv, names) for what, module, argv, names in rows]
    out[0].prepare = _finished_run
    interrupts = [
        ("Ctrl-C 0.3 s after start: collect", "flows.collect", ["--out", "{out}/l", "--episodes", "100000"], 0.3),
        ("Ctrl-C 8 s after start: collect", "flows.collect", ["--out", "{out}/l", "--episodes", "100000"], 8.0),
        (
            "Ctrl-C 0.3 s after start: evaluate",
            "flows.evaluate",
            ["--log-dir", "{out}/el", "--results-dir", "{out}/r"],
            0.3,
        ),
        ("Ctrl-C 0.5 s after start: bench", "dynplan.bench", ["world"], 0.5),
    ]
    out += [Case(8, what, module, argv, (), interrupt_after=t, env={}) for what, module, argv, t in interrupts]
    return out


def all_cases() -> list[Case]:
    return [*store_cases(), *road_result_cases(), *world_result_cases(), *world_cases(), *type_cases(),
            *environment_cases(), *output_cases(), *limit_cases()]  # fmt: skip
