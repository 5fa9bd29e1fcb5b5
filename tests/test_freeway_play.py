"""Playing Freeway: the keys step the real game as the evaluation does, the planner decides in the window as it does
in an evaluation (the oracle and the learned agent), and what was played reads back as a replay log. The window
runs headless (SDL's dummy video driver), fed real key events."""

from itertools import islice

import numpy as np
import pytest

pytest.importorskip("ale_py")
pygame = pytest.importorskip("pygame")

from dynplan.cli import InputError  # noqa: E402
from dynplan.logs.reader import read_episode_log  # noqa: E402
from dynplan.worlds.freeway.evaluation import play_turns, world_model_for  # noqa: E402
from dynplan.worlds.freeway.game import FreewayEpisode, FreewayGame  # noqa: E402
from dynplan.worlds.freeway.play import ACTION_KEYS, FreewayPlay  # noqa: E402
from dynplan.worlds.freeway.search import ChickenSearch  # noqa: E402
from flows.play import main  # noqa: E402
from flows.view import main as view  # noqa: E402
from flows.worlds import PlayOptions, play_window  # noqa: E402

pytestmark = pytest.mark.usefixtures("headless_window")
EPISODE = FreewayEpisode(mode=0, noop_start=5)


def test_help_lists_the_keys_and_a_bad_option_names_its_range(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["--world", "freeway", "--help"])
    shown = capsys.readouterr().out
    assert exit_.value.code == 0 and "W or UP" in shown and "--noop-start" in shown
    with pytest.raises(SystemExit) as exit_:
        main(["--world", "freeway", "--mode", "9"])
    assert exit_.value.code == 2 and "valid range [0, 7]" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["--world", "freeway", "--technique", "up"])
    assert "invalid choice: 'up'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["--world", "freeway", "--technique", "oracle", "--model-dir", "."])
    assert "--model-dir: only with --technique learned" in capsys.readouterr().err


def test_keys_step_the_real_game():
    keys = ["w"] * 30 + ["s"] * 5 + ["x"] * 10 + ["up"] * 20
    state = play_window(FreewayPlay(EPISODE, "zero"), PlayOptions(scale=1, fps=1000, script=keys))
    game = FreewayGame(EPISODE)
    ys = [game.step(ACTION_KEYS[key]).chicken.y for key in keys]
    assert [turn.step.chicken.y for turn in state.turns] == ys  # one emulator step a key, the same chicken
    assert [turn.action for turn in state.turns] == [ACTION_KEYS[key] for key in keys]
    assert all(turn.frames is None and turn.decision_ms is None for turn in state.turns)  # you chose, not a planner
    assert max(ys) > ys[0]


def test_the_oracle_plays_as_in_an_evaluation_and_its_replay_reads_back(tmp_path):
    out, picture = tmp_path / "played.mcap", tmp_path / "window.png"
    state = main(["--world", "freeway", "--mode", "0", "--noop-start", "5", "--technique", "oracle", "--watch",
                  "--fps", "1000", "--scale", "1", "--record", str(out), "--screenshot", str(picture),
                  "--script", ",".join(["k"] + ["f"] * 99)])  # fmt: skip
    assert state.search.horizon == 16 and state.t == 100  # K: 8 → 16; the planner stepped once a frame
    evaluated = list(islice(play_turns("oracle", EPISODE, ChickenSearch(horizon=16)), 100))
    assert [turn.action for turn in state.turns] == [turn.action for turn in evaluated]
    assert state.score == sum(turn.step.reward for turn in evaluated) >= 1
    log = read_episode_log(out)
    assert len(log.agent.action) == 100 and log.agent.t[0] == 5 and len(log.imagined) == 100
    assert log.agent.outcome[-1] == "running"  # quit before the game's end
    np.testing.assert_array_equal(log.imagined[5], state.world.frames[6:22])  # the oracle's lanes are the truth
    shot = pygame.image.load(str(picture))
    assert shot.get_size() == (4 * 152 + 5 * 8, 154 + 50 + 24 * 2)  # four panels, two lines of text below
    with pytest.raises(InputError, match="a log of the freeway world, not --world road's"):
        view([str(out), "--world", "road", "--screenshot", str(tmp_path / "view.png")])  # refused before the app


def test_the_learned_planner_decides_as_in_an_evaluation():
    model = world_model_for("learned")
    state = FreewayPlay(EPISODE, "learned", horizon=8, model=model)
    for _ in range(12):
        state.step(*state.planner_action())
    evaluated = list(islice(play_turns("learned", EPISODE, ChickenSearch(horizon=8), model=model), 12))
    assert [turn.action for turn in state.turns] == [turn.action for turn in evaluated]
    for played, reference in zip(state.turns, evaluated, strict=True):
        np.testing.assert_array_equal(played.frames, reference.frames)  # the same imagined lanes
    assert state.look_ahead().shape == (9, 154, 152)
    assert state.cycle_horizon() == 16 and state.look_ahead().shape == (17, 154, 152)  # a new look at the new k
    with pytest.raises(ValueError, match=r"action=3 is invalid; valid range \[0, 2\]"):
        state.step(3)
    with pytest.raises(ValueError, match="needs a world model"):
        FreewayPlay(EPISODE, "learned")
    state.reset()
    assert state.t == 0 and state.running and state.score == 0
