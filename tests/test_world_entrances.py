"""The world is checked at every entrance: a command of one world given another world's log or asked to train a
model of another world on a store refuses in one line naming the world it was given and the `--world` that reads
it, before anything runs."""

from __future__ import annotations

import pytest

pytest.importorskip("minigrid")  # the `minigrid` extra, in `dev`: installed wherever the suite runs


@pytest.fixture(scope="module")
def minigrid_log(tmp_path_factory):
    from dynplan.data.collect import log_path, record_episode

    folder = tmp_path_factory.mktemp("minigrid")
    record_episode(folder, 1_000_000, world_name="minigrid", n_frames=20)
    return log_path(folder, 1_000_000)


@pytest.mark.parametrize(
    ("command", "argv"),
    [("flows.replay", ["{log}", "--out", "{out}/r.mcap"]), ("flows.play", ["--log", "{log}", "--script", "up"])],
)
def test_the_roads_commands_refuse_another_worlds_log(tmp_path, minigrid_log, command, argv, capsys, monkeypatch):
    import importlib

    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    main = importlib.import_module(command).main
    filled = [a.format(log=minigrid_log, out=tmp_path) for a in argv]
    with pytest.raises(SystemExit) as stop:
        main(filled)
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert stop.value.code == 2 and f"{minigrid_log}: is a minigrid log, not one of the road world" in line
    assert line.endswith("read it with --world minigrid") and list(tmp_path.iterdir()) == []


def test_a_model_of_another_world_is_another_model_not_a_setting(tmp_path, recorded_logs, capsys):
    from dynplan.data.build import build_frame_store_from_logs
    from dynplan.data.store import list_logs
    from flows.train import main

    store = tmp_path / "s.zarr"
    build_frame_store_from_logs(store, list_logs(recorded_logs)[:1])
    with pytest.raises(SystemExit) as stop:
        main(["vqvae", "--store", str(store), "--out", str(tmp_path / "ck"), "--set", 'world="freeway"'])
    (line,) = capsys.readouterr().err.strip().splitlines()[-1:]
    assert stop.value.code == 2 and "--set world='freeway': --model default models the road world" in line
