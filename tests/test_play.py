"""Playing: the keyboard steers the agent as the planner would, the imagination rolls the world model forward and
gives the world back, the planner plays when asked, and what was played reads back as a replay log. The window
runs headless (SDL's dummy video driver), fed real key events."""

import os

import numpy as np
import pytest

from dynplan.env import RoadConfig, generate_world
from dynplan.logs.reader import read_episode_log
from dynplan.planning.config import MCTSConfig
from dynplan.planning.episode import run_episode
from dynplan.planning.forward import OracleModel
from dynplan.planning.mcts import MCTSPlanner
from dynplan.worlds.road.play import MOVE_KEYS, PlayState, action_of, build_state

pygame = pytest.importorskip("pygame")

from flows.play import main  # noqa: E402
from flows.worlds import PlayOptions, play_window  # noqa: E402

pytestmark = pytest.mark.usefixtures("headless_window")
SEED = 2_000_003
KEY_OF_ACTION = {action_of(heading): key for key, heading in MOVE_KEYS.items() if len(key) == 1}


def test_help_lists_the_modes_and_the_keys(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["--help"])
    assert exit_.value.code == 0
    out = capsys.readouterr().out
    for needle in ("you play", "imagination", "planner plays", "W E D C X Z A Q", "SPACE", "--record", "--watch"):
        assert needle in out, needle


def test_every_heading_has_a_key_and_a_bad_option_names_itself(capsys):
    assert sorted(KEY_OF_ACTION) == list(range(8))
    with pytest.raises(SystemExit) as exit_:
        main(["--scale", "40"])
    assert exit_.value.code == 2 and "--scale" in capsys.readouterr().err


@pytest.mark.parametrize("world", [["--no-imagination"], ["--world", "freeway"]])
def test_without_a_display_the_window_is_one_line_and_a_script_plays_headless(world, monkeypatch, capsys, tmp_path):
    for name in ("DISPLAY", "WAYLAND_DISPLAY", "SDL_VIDEODRIVER"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setattr("sys.platform", "linux")
    with pytest.raises(SystemExit) as exit_:
        main(world)
    assert exit_.value.code == 2
    error = capsys.readouterr().err.strip().splitlines()[-1]
    assert "no display to open the window on" in error and "--script KEYS" in error
    shot = tmp_path / "shot.png"
    main([*world, "--script", "space,escape", "--screenshot", str(shot)])
    assert shot.stat().st_size > 0 and os.environ["SDL_VIDEODRIVER"] == "dummy"


def test_keys_play_the_oracles_path_to_the_goal():
    world = generate_world(RoadConfig(), SEED)
    planner = MCTSPlanner(MCTSConfig(rollout_steps=3), 1.0, RoadConfig().max_steps, seed=0)
    reference = run_episode(world, planner, OracleModel(world), 1.0, 3)
    assert reference.outcome == "goal"
    state = build_state(seed=SEED, imagination=False)
    script = [KEY_OF_ACTION[int(a)] for a in reference.track.action]
    played = play_window(state, PlayOptions(scale=2, fps=1000, script=script))
    assert played.outcome == "goal" and len(played.track.action) == reference.steps
    np.testing.assert_allclose(played.track.position, reference.track.position)


def test_the_imagination_rolls_the_model_forward_and_gives_the_world_back(tmp_path):
    state = build_state(seed=SEED)
    out = tmp_path / "played.mcap"
    play_window(state, PlayOptions(scale=2, fps=1000, script=["i", "w", "w", "i", "d"], record=str(out)))
    assert state.place == "world" and state.t == 4 + 3 and state.running
    log = read_episode_log(out)
    assert list(log.agent.action) == [action_of(90), action_of(90), action_of(0)]
    assert sorted(log.imagined) == [4, 5]  # the imagination's frames at t + 1 of its two steps
    imagined = log.imagined[5][0]
    assert imagined.shape == (48, 48) and imagined.dtype == np.uint8
    assert (imagined == log.frames[6]).mean() > 0.8  # imagined from real frames 2 … 5, then its own: near the truth


def test_an_agent_is_judged_on_the_imagined_frames():
    from dynplan.planning.forward import ForwardModel, Prediction

    class Wall(ForwardModel):
        name = "wall"

        def predict(self, observed, k):
            return Prediction.from_frames(np.full((k, 48, 48), 100, np.uint8))  # an obstacle everywhere

    state = PlayState(generate_world(RoadConfig(), SEED), imagination=Wall())
    state.toggle_imagination()
    assert state.step(action_of(90)) == "death"


def test_the_planner_plays_and_its_horizon_changes(tmp_path):
    out = tmp_path / "watched.mcap"
    state = main(["--seed", str(SEED), "--watch", "--no-imagination", "--fps", "1000", "--scale", "2", "--record",
                    str(out), "--script", ",".join(["k"] + ["f"] * 80)])  # fmt: skip
    assert state.k == 5 and state.outcome == "goal"
    log = read_episode_log(out)
    assert log.agent.outcome[-1] == "goal" and len(log.imagined) == len(log.agent.action)
    assert {len(frames) for frames in log.imagined.values()} <= {5, 4, 3, 2, 1}
