"""docs/worlds.md's "Add a world", run as it stands: its Python blocks are written into a package of their own, its
entry point registers that package's world, and the commands record, store and verify the world's episodes — a
world added without a line of dynplan changed."""

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "worlds.md"


def tutorial_blocks(language: str) -> list[str]:
    """The code blocks of `language` in the page's "Add a world" section, in order."""
    section = PAGE.read_text().split("## Add a world", 1)[1].split("\n## ", 1)[0]
    return re.findall(rf"```{language}\n(.*?)```", section, flags=re.S)


@pytest.fixture(scope="module")
def belt(tmp_path_factory) -> Path:
    """A folder holding the tutorial's package `belt` and its installed metadata (its entry points)."""
    site = tmp_path_factory.mktemp("site")
    (site / "belt.py").write_text("\n\n".join(tutorial_blocks("python")))
    toml = tutorial_blocks("toml")[0]
    name, reference = re.search(r'^(\w+) = "([\w.:]+)"', toml, flags=re.M).groups()
    info = site / "belt-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: belt\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text(f"[dynplan.worlds]\n{name} = {reference}\n")
    return site


def _run(site: Path, *args: str) -> subprocess.CompletedProcess:
    """`python ARGS` with the tutorial's package installed beside dynplan (a process of its own: the registry reads
    the entry points once)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), str(ROOT)])}
    return subprocess.run([sys.executable, *args], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)


def _command(site: Path, *args: str) -> subprocess.CompletedProcess:
    return _run(site, "-m", *args)


def _probe(site: Path, code: str):
    """What `code` (Python that sets `found`) finds in a process of its own, as JSON."""
    done = _run(site, "-c", f"import json\n{code}\nprint(json.dumps(found))")
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.splitlines()[-1])


def test_the_tutorials_world_is_registered_and_records_the_same_bytes(belt):
    probe = """
from dynplan.world import world, world_names
w = world("belt")
e = w.record(w.recording, 3)
again = w.record(w.recording, 3)
found = [world_names(), w.id, e.frames.shape, sorted(set(e.frames.ravel().tolist())),
         bool((again.frames == e.frames).all()), w.load().presets == {}]
"""
    names, world_id, shape, values, same, no_presets = _probe(belt, probe)
    assert names[0] == "road" and "belt" in names and names[1:] == sorted(names[1:])  # the default, then by name
    assert world_id == "belt-v1" and shape == [40, 16, 16]
    assert values == [0, 200] and same and no_presets


@pytest.mark.slow
def test_the_commands_record_store_and_verify_the_tutorials_world(belt, tmp_path):
    logs, store = tmp_path / "belt_logs", tmp_path / "belt.zarr"
    recorded = _command(belt, "flows.collect", "--world", "belt", "--episodes", "3", "--out", str(logs), "--json")
    assert recorded.returncode == 0, recorded.stderr
    assert json.loads(recorded.stdout.splitlines()[-1])["written"] == 3
    probe = f"""
from dynplan.logs.reader import read_episode_log
log = read_episode_log({str(logs / "episode_0000000001.mcap")!r})
found = [log.entry.name, log.goal is None, list(log.frames.shape), bool((log.frames[1] != log.frames[0]).any())]
"""
    assert _probe(belt, probe) == ["belt", True, [40, 16, 16], True]  # its frames, no goal, the boxes moving
    again = _command(belt, "flows.collect", "--world", "belt", "--episodes", "3", "--out", str(logs), "--json")
    assert json.loads(again.stdout.splitlines()[-1])["written"] == 0  # the same bytes: every log kept
    built = _command(belt, "flows.build_datasets", str(logs), "--world", "belt", "--out", str(store))
    assert built.returncode == 0, built.stderr
    verified = _command(belt, "flows.build_datasets", "--verify", str(store), str(logs))
    assert verified.returncode == 0, verified.stdout + verified.stderr
    wrong = _command(belt, "flows.build_datasets", str(logs), "--out", str(tmp_path / "road.zarr"))
    assert wrong.returncode != 0 and "belt world" in wrong.stderr
