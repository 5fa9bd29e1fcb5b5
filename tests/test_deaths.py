"""Death causes: the classification on hand-made frames, and replays of recorded deaths."""

import json

import numpy as np
import pytest

from dynplan.data.collect import record_episode
from dynplan.evaluation.cases import EVAL_SEED_START, Case
from dynplan.evaluation.protocol import run_case
from dynplan.evaluation.provenance import begin_run
from dynplan.evaluation.store import Run
from lab.deaths import CAUSES, classify_death, main, replay_death

SEDAN = 144
#: Evaluation seed on which the zero-model agent (it predicts an empty road) dies at agent speed 1.0, k = 1 and 3.
DYING_SEED = EVAL_SEED_START + 1


def frames_with(*runs: tuple[int, int, int]) -> np.ndarray:
    """A 48 × 48 frame with obstacle runs (row, first column, length)."""
    frame = np.zeros((48, 48), np.uint8)
    for y, x, n in runs:
        frame[y, x : x + n] = SEDAN
    return frame


@pytest.mark.parametrize(
    ("before", "after", "predicted", "position", "cause"),
    [
        (frames_with(), frames_with(), frames_with(), (-1, 5), "off_grid"),
        (frames_with((10, 4, 3)), frames_with((10, 6, 3)), frames_with((10, 6, 3)), (10, 7), "foreseen"),
        (frames_with(), frames_with((10, 0, 3)), frames_with(), (10, 1), "spawned"),
        (frames_with((10, 4, 3)), frames_with((10, 6, 3)), frames_with((10, 5, 3)), (10, 8), "displaced"),
        (frames_with((10, 4, 3)), frames_with((10, 6, 3)), frames_with(), (10, 8), "lost"),
        # an obstacle elsewhere in the prediction is not this one
        (frames_with((10, 4, 3)), frames_with((10, 6, 3)), frames_with((10, 30, 3), (11, 6, 3)), (10, 8), "lost"),
        # a new arrival beside the agent, with another obstacle far along the lane a step earlier
        (frames_with((10, 30, 3)), frames_with((10, 0, 3), (10, 32, 3)), frames_with((10, 32, 3)), (10, 2), "spawned"),
    ],
)
def test_classify_death(before, after, predicted, position, cause):
    assert cause in CAUSES
    assert classify_death(before, after, predicted, position) == cause


def test_classify_death_refuses_a_pixel_without_an_obstacle():
    with pytest.raises(ValueError, match="not a collision"):
        classify_death(frames_with(), frames_with(), frames_with(), (10, 8))


@pytest.fixture(scope="module")
def dying_case(tmp_path_factory):
    logs, results = tmp_path_factory.mktemp("logs"), tmp_path_factory.mktemp("results")
    record_episode(logs, DYING_SEED)
    run, dying = Run(results), [Case("zero", 1.0, k, DYING_SEED) for k in (1, 3)]
    begin_run(run, "evaluation", dying, logs, "test")
    for case in dying:
        assert run_case(case, logs, run)["outcome"] == "death"
    return logs, results


def test_replayed_deaths_are_those_recorded_and_unforeseen_by_an_empty_prediction(dying_case):
    logs, results = dying_case
    record = next(r for r in Run(results).rows() if r["rollout_steps"] == 3)
    death = replay_death(Case("zero", 1.0, 3, DYING_SEED), str(logs))
    assert death.t + 1 == record["steps"] + 4  # first decision at t = 4; died on the frame after the last decision
    assert death.cause in {"spawned", "lost"}  # an empty prediction foresees and displaces nothing


def test_command_line_summarises_and_writes_the_causes(dying_case, tmp_path):
    logs, results = dying_case
    out = tmp_path / "deaths.json"
    rows = main(["--technique", "zero", "--rollout-steps", "1", "3", "--results-dir", str(results),
                 "--log-dir", str(logs), "--out", str(out)])  # fmt: skip
    assert [(r["k"], r["episodes"], r["deaths"]) for r in rows] == [(1, 1, 1), (3, 1, 1)]
    assert all(sum(r[c] for c in CAUSES) == r["deaths"] for r in rows)
    saved = json.loads(out.read_text())
    assert saved["summary"] == rows and len(saved["deaths"]) == 2
    with pytest.raises(SystemExit):
        main(["--technique", "zero", "--agent-speed", "0.5", "--results-dir", str(results)])


def test_deaths_replay_with_the_caution_their_result_records(monkeypatch):
    import lab.deaths as deaths

    seen = []
    monkeypatch.setattr(deaths, "replay_death", lambda case, log, playouts, models, caution: seen.append(caution))
    record = {"technique": "samples5", "agent_speed": 1.0, "rollout_steps": 1, "seed": 1, "model": "default",
              "outcome": "death", "playouts": 100}  # fmt: skip
    deaths.death_causes([record, {**record, "occupancy": 0.1}, {**record, "occupancy": 0.1, "margin": 1},
                         {**record, "outcome": "goal"}])  # fmt: skip
    # absent: off (a record without the field), not the configuration's current own
    off = {"occupancy": 0, "margin": 0}
    assert seen == [off, {**off, "occupancy": 0.1}, {**off, "occupancy": 0.1, "margin": 1}]


def test_a_death_played_with_a_setting_the_code_lacks_is_not_replayed():
    from lab.deaths import recorded_caution

    record = {"technique": "samples5", "agent_speed": 1.0, "rollout_steps": 1, "seed": 7, "model": "default",
              "outcome": "death", "playouts": 100, "occupancy": 0.1}  # fmt: skip
    assert recorded_caution(record) == {"occupancy": 0.1, "margin": 0}
    with pytest.raises(ValueError, match="seed 7 was played with span, which this code does not have"):
        recorded_caution({**record, "span": 1})
