"""Prefect artifacts of the flows, read back through Prefect's client from a real (temporary) Prefect server: an
evaluation's Table 1 under its stable key, its progress, and keys Prefect accepts whatever a run is called."""

import json

import pytest

from dynplan.data.collect import record_episode
from dynplan.evaluation.cases import EVAL_SEED_START
from flows.artifacts import artifact_key, read_artifacts


@pytest.mark.parametrize(("name", "key"), [("quick", "table1-quick"), ("Run 2 / B", "table1-run-2-b"),
                                           ("validation_paper_margin1", "table1-validation-paper-margin1"),
                                           ("-x--", "table1-x")])  # fmt: skip
def test_keys_hold_only_what_prefect_accepts(name, key):
    assert artifact_key("table1", name) == key


def test_an_evaluation_publishes_its_table_and_progress(tmp_path, prefect_api):
    from dynplan.evaluation.agent import AgentSpec
    from dynplan.evaluation.cases import CasePlan
    from dynplan.worlds.road.evaluate import RoadEvaluation
    from flows.worlds import evaluate_world

    for i in range(2):
        record_episode(tmp_path / "logs", EVAL_SEED_START + i)
    plan = CasePlan(techniques=["oracle", "random"], agent_speeds=[1.0], rollout_steps=[1], episodes=2)
    kwargs = dict(plan=plan, agent=AgentSpec(playouts=5), log_dir=str(tmp_path / "logs"),
                  results_dir=str(tmp_path / "results"), run="trial_run")  # fmt: skip
    request = RoadEvaluation(**kwargs).model_dump(mode="json")
    rows = evaluate_world("road", request, "python -m flows.evaluate")
    (table,) = read_artifacts(key="table1-trial-run")
    assert table.type == "table" and json.loads(table.data) == [
        {k: r.get(k) for k in json.loads(table.data)[0]} for r in rows
    ]
    played_per_row = {(r["technique"], r["G"] + r["T"] + r["D"]) for r in json.loads(table.data)}
    assert played_per_row == {("oracle", 2), ("random", 2)}
    assert "| 2× oracle (ours) |" in table.description
    (played,) = [a for a in read_artifacts(kind="progress") if "trial_run" in a.description]
    assert played.data == 100.0 and played.description == "episodes played into run 'trial_run': 4 of 4"
    evaluate_world("road", request, "python -m flows.evaluate")  # nothing left to play: a second version of the table
    assert [json.loads(a.data) for a in read_artifacts(key="table1-trial-run")] == [json.loads(table.data)] * 2
