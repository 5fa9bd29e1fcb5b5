"""The offline Foxglove viewer: the server answers only what it serves (byte ranges exact), the app's install
refuses what is not the pinned app, every JSON schema we write is one Foxglove's parser takes, bad command lines
are one line, and — in a real headless Chromium — a replay log written by flows.replay opens in Foxglove Studio
1.48 with every topic listed, no problem reported, every panel drawn and no request leaving 127.0.0.1."""

from __future__ import annotations

import json
import os
import re
import select
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
import jsonschema
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader
from mcap.writer import Writer
from PIL import Image

import flows.view
from dynplan.cli import InputError
from dynplan.data.collect import record_episode
from dynplan.evaluation.cases import EVAL_SEED_START
from dynplan.logs import writer
from dynplan.logs.format import REPLAY_LAYOUT, SEARCH_JSON_SCHEMA, STEP_JSON_SCHEMA, STUDIO_LAYOUT, layout_topics
from dynplan.logs.reader import inspect_log
from dynplan.view import app as viewer_app
from dynplan.view.browser import Browser, find_chromium
from dynplan.view.capture import CaptureSettings, capture
from dynplan.view.server import ViewServer, routes

ROOT = Path(__file__).resolve().parents[1]
PYTHON = sys.executable
#: The search schema as it was when Foxglove refused the topic: `goal` a union with null.
REFUSED_SEARCH_SCHEMA = {
    **SEARCH_JSON_SCHEMA,
    "properties": {**SEARCH_JSON_SCHEMA["properties"], "goal": {"type": ["object", "null"]}},
}


# --- schemas and layouts -------------------------------------------------------------------------------------


def foxglove_fields(schema: dict, path: str = "") -> list[str]:
    """Foxglove's JSON-schema parser's rules (Studio 1.48, `parseJsonSchema`): each field one type of boolean,
    string, number, integer, object (with properties) or array (whose items are one such type). What breaks
    them, named."""
    wrong = []
    for name, field in schema.get("properties", {}).items():
        where, kind = f"{path}{name}", field.get("type")
        if kind == "object":
            wrong += foxglove_fields(field, where + ".") if "properties" in field else [f"{where}: no properties"]
        elif kind == "array":
            item = field.get("items", {})
            if item.get("type") == "object":
                wrong += foxglove_fields(item, where + "[].")
            elif item.get("type") not in ("boolean", "string", "number", "integer"):
                wrong.append(f"{where}: items of type {item.get('type')!r}")
        elif kind not in ("boolean", "string", "number", "integer"):
            wrong.append(f"{where}: type {kind!r}")
    return wrong


def test_every_json_schema_we_write_is_one_foxglove_parses():
    assert foxglove_fields(STEP_JSON_SCHEMA) == []
    assert foxglove_fields(SEARCH_JSON_SCHEMA) == []
    assert foxglove_fields(REFUSED_SEARCH_SCHEMA) == ["goal: type ['object', 'null']"]  # as Foxglove refused it


@pytest.fixture(scope="module")
def episode_log(tmp_path_factory) -> Path:
    """The first evaluation episode's log (407 frames: 40.6 s of log time)."""
    return Path(record_episode(tmp_path_factory.mktemp("eval_logs"), EVAL_SEED_START).path)


@pytest.fixture(scope="module")
def replay_log(tmp_path_factory, episode_log) -> Path:
    """A replay log written by `python -m flows.replay` (the learned default agent, so that it has imagined
    frames and predicted goals)."""
    out = tmp_path_factory.mktemp("view") / "replay.mcap"
    done = subprocess.run([PYTHON, "-m", "flows.replay", str(episode_log), "--planner", "samples5", "--out", str(out)],
                          cwd=ROOT, capture_output=True, text=True, timeout=600)  # fmt: skip
    assert done.returncode == 0, done.stderr
    return out


@pytest.mark.slow
def test_json_rows_keep_to_the_schemas_they_are_written_with(replay_log):
    with open(replay_log, "rb") as f:
        reader = make_reader(f)
        rows = 0
        for schema, _channel, message in reader.iter_messages(topics=["/planner/search", "/agent/step"]):
            jsonschema.validate(json.loads(message.data), json.loads(schema.data))
            rows += 1
    assert rows > 10


@pytest.mark.slow
def test_every_layout_reads_only_topics_a_replay_log_has(replay_log):
    topics = set(inspect_log(replay_log).topics)
    for layout in (REPLAY_LAYOUT, STUDIO_LAYOUT):
        assert layout_topics(layout) <= topics, (layout.name, layout_topics(layout) - topics)
    assert layout_topics(REPLAY_LAYOUT) == layout_topics(STUDIO_LAYOUT)  # one layout in two panel dialects
    studio = json.loads(STUDIO_LAYOUT.read_text())["configById"]
    assert {key.split("!")[0] for key in studio} == {"ImageViewPanel", "Plot", "RawMessages"}


# --- the server ----------------------------------------------------------------------------------------------


@pytest.fixture()
def served(tmp_path):
    """A server of a fake app folder (two files and a manifest), a layout and a log of 1,000 known bytes."""
    app = tmp_path / "app"
    (app / "assets").mkdir(parents=True)
    (app / "assets" / "index.js").write_text("// app")
    (app / "react.production.min.js").write_text("// react")
    (app / viewer_app.MANIFEST).write_text(json.dumps({"files": {"assets/index.js": 6, "react.production.min.js": 8}}))
    (tmp_path / "secret.txt").write_text("not served")
    log = tmp_path / "a log.mcap"
    log.write_bytes(bytes(range(256)) * 3 + bytes(232))
    table, (log_url,) = routes(app, STUDIO_LAYOUT, [log])
    with ViewServer(table) as server:
        yield server.origin, log_url, log.read_bytes()


def test_the_server_answers_only_what_it_serves(served):
    origin, log_url, data = served
    assert httpx.get(origin + "/").text.startswith("<!doctype html>")
    assert httpx.get(origin + "/app/assets/index.js").text == "// app"
    assert httpx.get(origin + "/layout.json").json() == json.loads(STUDIO_LAYOUT.read_text())
    assert httpx.get(origin + log_url).content == data
    for path in ("/secret.txt", "/app/manifest.json", "/app/../secret.txt", "/app/%2e%2e/secret.txt", "/logs/0/",
                 "/logs/1/a%20log.mcap", "/etc/passwd", "//etc/passwd", "/app/assets/"):  # fmt: skip
        assert httpx.get(origin + path).status_code == 404, path
    assert httpx.post(origin + "/").status_code == 501
    for header in ("bytes=5-3", "bytes=" + "9" * 5000 + "-", "bytes=0-1,4-5", "items=0-1"):  # not one byte range
        whole = httpx.get(origin + log_url, headers={"Range": header})
        assert whole.status_code == 200 and whole.content == data, header  # ignored: the whole file
    assert httpx.get(origin + "/", headers={"Host": "rebound.example"}).status_code == 403
    head = httpx.head(origin + log_url)
    assert head.headers["content-length"] == str(len(data)) and head.headers["accept-ranges"] == "bytes"


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(first=st.integers(0, 1100), length=st.integers(1, 1100), form=st.sampled_from(["a-b", "a-", "-n"]))
def test_a_byte_range_is_exactly_those_bytes(served, first, length, form):
    origin, log_url, data = served
    header = {"a-b": f"bytes={first}-{first + length - 1}", "a-": f"bytes={first}-", "-n": f"bytes=-{length}"}[form]
    response = httpx.get(origin + log_url, headers={"Range": header})
    expected = {"a-b": data[first : first + length], "a-": data[first:], "-n": data[-length:]}[form]
    if form != "-n" and first >= len(data):
        assert response.status_code == 416 and response.headers["content-range"] == f"bytes */{len(data)}"
        return
    assert response.status_code == 206 and response.content == expected
    start = len(data) - len(expected) if form == "-n" else first
    assert response.headers["content-range"] == f"bytes {start}-{start + len(expected) - 1}/{len(data)}"


# --- the app's install ---------------------------------------------------------------------------------------


def test_a_tarball_that_is_not_the_pinned_one_is_refused(tmp_path):
    tarball = tmp_path / "react-17.0.2.tgz"
    tarball.write_bytes(b"not react")
    with pytest.raises(InputError, match=r"react-17.0.2.tgz: its sha512 is sha512-.*not the pinned sha512-gnhPt"):
        viewer_app._check_integrity(viewer_app.PACKAGES[1], tarball)


def test_an_incomplete_app_folder_is_not_installed(tmp_path):
    folder = tmp_path / viewer_app.APP_FOLDER
    folder.mkdir()
    (folder / "a.js").write_text("abc")
    manifest = {"version": viewer_app.STUDIO_VERSION, "files": {"a.js": 3}}
    (folder / viewer_app.MANIFEST).write_text(json.dumps(manifest))
    assert viewer_app.installed_app(tmp_path) == folder
    (folder / "a.js").write_text("ab")  # resized: an interrupted copy, or edited
    assert viewer_app.installed_app(tmp_path) is None
    (folder / viewer_app.MANIFEST).write_text("{")
    assert viewer_app.installed_app(tmp_path) is None


@pytest.mark.parametrize("name", ["../../secret", "/etc/hostname", "out/secret"])
def test_an_app_manifest_naming_a_file_outside_its_folder_is_not_served(tmp_path, name):
    """A cache whose manifest names a file outside the app's folder (by `..`, an absolute path or a link out) is no
    installed app, and the server's table refuses it naming the manifest: nothing outside the folder is served."""
    folder = tmp_path / "cache" / viewer_app.APP_FOLDER
    folder.mkdir(parents=True)
    (tmp_path / "secret").write_text("private")
    (folder / "out").symlink_to(tmp_path)
    manifest = {"version": viewer_app.STUDIO_VERSION, "files": {name: Path("/etc/hostname").stat().st_size}}
    if name != "/etc/hostname":
        manifest["files"][name] = len("private")
    (folder / viewer_app.MANIFEST).write_text(json.dumps(manifest))
    assert viewer_app.installed_app(tmp_path / "cache") is None
    with pytest.raises(InputError, match=rf"manifest.json: names '{re.escape(name)}', outside the app's folder"):
        routes(folder, tmp_path / "layout.json", [])


def test_without_npm_the_install_says_so(tmp_path, monkeypatch):
    monkeypatch.setenv("PATH", str(tmp_path))
    with pytest.raises(InputError, match="npm not found"):
        viewer_app.install(tmp_path / "cache")
    assert not (tmp_path / "cache").exists()


# --- the command ---------------------------------------------------------------------------------------------


def _view(*argv: str, **env: str) -> subprocess.CompletedProcess:
    return subprocess.run([PYTHON, "-m", "flows.view", *argv], cwd=ROOT, capture_output=True, text=True,
                          timeout=120, env={**os.environ, **env})  # fmt: skip


@pytest.mark.slow
def test_bad_inputs_are_one_line_and_exit_2(tmp_path, episode_log):
    foreign = tmp_path / "foreign.mcap"
    with open(foreign, "wb") as f:
        mcap = Writer(f)
        mcap.start()
        channel = mcap.register_channel("/x", "json", mcap.register_schema("x", "jsonschema", b"{}"))
        mcap.add_message(channel, 1, b"{}", 1)
        mcap.finish()
    truncated = tmp_path / "truncated.mcap"
    truncated.write_bytes(episode_log.read_bytes()[: episode_log.stat().st_size // 2])
    busy = socket.socket()
    busy.bind(("127.0.0.1", 0))
    busy.listen()
    log, shot, port = str(episode_log), str(tmp_path / "s.png"), str(busy.getsockname()[1])
    cases = {
        "no such episode log": ([str(tmp_path / "missing.mcap")], {}),
        "not a dynplan episode log": ([str(foreign)], {}),
        "truncated or corrupt": ([str(truncated)], {}),
        f"--port {port}: already in use": ([log, "--port", port], {}),
        "not found on PATH": ([log, "--screenshot", shot], {"DYNPLAN_CHROMIUM": "nope"}),
        "past the log's end; valid range [0, 40.6]": ([log, "--screenshot", shot, "--at", "41"], {}),
        "npm not found": ([log, "--cache", str(tmp_path / "empty")], {"PATH": str(Path(PYTHON).parent)}),
    }
    with busy:
        for expected, (argv, env) in cases.items():
            done = _view(*argv, **env)
            assert done.returncode == 2, (expected, done.stderr)
            assert done.stderr.count("\n") == 1 and expected in done.stderr, (expected, done.stderr)
    assert not (tmp_path / "s.png").exists() and not (tmp_path / "empty" / viewer_app.APP_FOLDER).exists()


# --- in a real browser ---------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def studio():
    """The installed app (the viewer's own install step fetches it on first use) and the Chromium to show it."""
    try:
        chromium = find_chromium()
    except InputError as missing:
        if os.environ.get("DYNPLAN_REQUIRE_BROWSER"):
            pytest.fail(f"DYNPLAN_REQUIRE_BROWSER is set: {missing}")
        pytest.skip(f"{missing} (.ci/run installs it)")
    return viewer_app.install(viewer_app.default_cache()), chromium


def _image_shows_the_world(png: Path, box) -> bool:
    """The screenshot's pixels in `box` hold the world's colours: its black road, and grey obstacles."""
    x, y, w, h = (round(v) for v in box)
    crop = np.asarray(Image.open(png).convert("RGB"))[y : y + h, x : x + w].astype(int)
    grey = (crop.max(axis=2) - crop.min(axis=2) < 8) & (crop.min(axis=2) > 40) & (crop.max(axis=2) < 250)
    return (crop.max(axis=2) < 24).mean() > 0.1 and grey.sum() > 50


@pytest.mark.slow
def test_a_replay_log_opens_in_foxglove_with_every_topic_and_no_problem(studio, replay_log, tmp_path):
    shot = tmp_path / "shot.png"
    report = flows.view.main([str(replay_log), "--screenshot", str(shot), "--at", "2"])
    log_topics = {name: schema for name, (schema, _count) in inspect_log(replay_log).topics.items()}
    assert report.topics == log_topics  # every topic listed, with its schema: none refused
    assert report.problems == ()
    assert report.outside_requests == () and report.log_requests > 0  # the recorder sees the app's reads
    assert report.complete and report.page_errors == ()
    kinds = {panel.id: panel for panel in report.panels}
    assert set(kinds) == set(json.loads(STUDIO_LAYOUT.read_text())["configById"])
    assert all(panel.drawn for panel in report.panels), [p.id for p in report.panels if not p.drawn]
    for panel in report.panels:
        if panel.kind == "ImageViewPanel":
            assert _image_shows_the_world(shot, panel.canvas), panel.id
    assert Image.open(shot).size == CaptureSettings().size


@pytest.fixture(scope="module")
def freeway_replay(tmp_path_factory) -> Path:
    """A Freeway replay log: 60 frames of mode 0 and 40 steps of the zero planner from NOOP start 2."""
    pytest.importorskip("ale_py")
    from itertools import islice

    from dynplan.logs.writer import write_episode_log
    from dynplan.worlds.freeway.evaluation import play_turns
    from dynplan.worlds.freeway.game import FreewayEpisode, record_mode
    from dynplan.worlds.freeway.replay import track
    from dynplan.worlds.freeway.search import ChickenSearch

    turns = list(islice(play_turns("zero", FreewayEpisode(mode=0, noop_start=2), ChickenSearch(horizon=2)), 40))
    imagined = {2 + i: turn.frames[1:] for i, turn in enumerate(turns)}
    out = tmp_path_factory.mktemp("freeway") / "replay.mcap"
    return write_episode_log(out, record_mode(0, 60), agent=track(turns, 2), imagined=imagined)


def test_each_world_has_a_layout_of_the_topics_its_replays_have(freeway_replay):
    from dynplan.world import world

    parts = world("freeway").load()
    topics = set(inspect_log(freeway_replay).topics)
    for layout in (parts.layout, parts.studio_layout):
        assert layout_topics(layout) == topics - {"/world/goal"}, layout  # every panel has its topic
    assert layout_topics(parts.layout) == layout_topics(parts.studio_layout)  # one layout in two dialects


@pytest.mark.slow
def test_a_freeway_replay_opens_with_its_own_layout_every_panel_drawn(studio, freeway_replay, tmp_path):
    from dynplan.world import world

    shot = tmp_path / "freeway.png"
    report = flows.view.main([str(freeway_replay), "--screenshot", str(shot), "--at", "2"])
    layout = world("freeway").load().studio_layout
    assert {panel.id for panel in report.panels} == set(json.loads(layout.read_text())["configById"])
    assert report.problems == () and report.complete and report.outside_requests == ()
    assert all(panel.drawn for panel in report.panels), [p.id for p in report.panels if not p.drawn]


@pytest.mark.slow
def test_a_refused_schema_and_a_blank_panel_are_seen(studio, tmp_path, monkeypatch, episode_log):
    """The checks above can fail: a replay written with the goal schema Foxglove refuses shows a problem naming the
    topic and empty search plots; the current app's layout in Studio 1.48 leaves its image panels blank."""
    from dynplan.evaluation.agent import AgentSpec
    from dynplan.evaluation.replay import replay

    monkeypatch.setattr(writer, "SEARCH_JSON_SCHEMA", REFUSED_SEARCH_SCHEMA)
    log = tmp_path / "refused.mcap"
    replay(episode_log, AgentSpec(technique="oracle", rollout_steps=3, playouts=20), out=log)
    app, chromium = studio
    report = capture(app, STUDIO_LAYOUT, log, tmp_path / "refused.png", chromium, CaptureSettings(at_s=2.0))
    assert any("/planner/search" in p and "goal" in p for p in report.problems), report.problems
    assert "/planner/search" not in report.topics
    blank = {p.id for p in report.panels if not p.drawn}
    assert {"Plot!visits", "Plot!value"} <= blank and "Plot!path" not in blank
    report = capture(app, REPLAY_LAYOUT, episode_log, tmp_path / "blank.png", chromium, CaptureSettings(timeout_s=8))
    images = [p for p in report.panels if p.kind == "Image"]
    assert len(images) == 3 and not any(p.drawn for p in images)


@pytest.mark.slow
def test_a_screenshot_whose_panels_do_not_draw_exits_1_naming_them(studio, replay_log, tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(flows.view, "studio_layout", lambda log: REPLAY_LAYOUT)  # the other dialect: images stay blank
    with pytest.raises(SystemExit) as exit:
        flows.view.main([str(replay_log), "--screenshot", str(tmp_path / "blank.png"), "--timeout", "8"])
    out = capsys.readouterr().out
    assert exit.value.code == 1 and "within --timeout" in out, out
    assert out.count("shows nothing") == 3 and "panel Image!" in out, out


@pytest.mark.slow
def test_the_browser_records_requests_of_the_page_and_its_workers(studio, tmp_path):
    """What `outside_requests` is made of sees a page's and a worker's requests elsewhere (none of which is sent)."""
    (tmp_path / "index.html").write_text("<script>fetch('http://192.0.2.1/from-page'); new Worker('w.js');</script>")
    (tmp_path / "w.js").write_text("fetch('http://outside.example/from-worker');")
    outside = {"http://192.0.2.1/from-page", "http://outside.example/from-worker"}
    table = {"/": tmp_path / "index.html", "/w.js": tmp_path / "w.js"}
    with ViewServer(table) as server, Browser(studio[1]) as browser:
        browser.open(server.origin + "/")
        deadline = time.monotonic() + 10
        while not (outside <= set(browser.requests) and len(browser.errors) >= 2) and time.monotonic() < deadline:
            browser.evaluate("1")  # reads the events that arrived: a failed fetch is reported after its request
            time.sleep(0.1)
    assert outside <= set(browser.requests), browser.requests
    assert len(browser.errors) == 2  # each fetch failed: the page reached nothing elsewhere


def _interruptible() -> None:
    """Let the child take SIGINT even where this suite runs in the background (which ignores it)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.mark.slow
def test_the_viewer_serves_until_interrupted(studio, replay_log):
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}  # the URL must come through a pipe
    process = subprocess.Popen([PYTHON, "-m", "flows.view", str(replay_log)], cwd=ROOT, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True, env=env, preexec_fn=_interruptible)  # fmt: skip
    try:
        ready, _, _ = select.select([process.stdout], [], [], 60)
        assert ready, "no URL within 60 s"
        url = process.stdout.readline().split(": ", 1)[1].strip()
        origin = url.split("/?")[0]
        assert origin.startswith("http://127.0.0.1:") and "layoutId=dynplan" in url
        assert httpx.get(url).text.startswith("<!doctype html>")
        size = replay_log.stat().st_size
        piece = httpx.get(f"{origin}/logs/0/replay.mcap", headers={"Range": "bytes=0-7"})
        assert piece.content == replay_log.read_bytes()[:8] and piece.headers["content-range"] == f"bytes 0-7/{size}"
        assert httpx.get(origin + "/pyproject.toml").status_code == 404
        port = origin.rsplit(":", 1)[1]
        assert httpx.get(url, headers={"Host": f"rebound.example:{port}"}).status_code == 403  # DNS rebinding
    finally:
        process.send_signal(signal.SIGINT)
        out, err = process.communicate(timeout=30)
    assert process.returncode == 0 and "stopped" in out and err == "", err
