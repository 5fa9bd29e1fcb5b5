"""Evaluation protocol, Table 1 aggregation, and replay (library, flow and command line)."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from dynplan.config import ConfigError
from dynplan.data.collect import log_path, record_episode
from dynplan.evaluation.agent import AgentSpec
from dynplan.evaluation.cases import EVAL_SEED_START, Case, CasePlan, cases
from dynplan.evaluation.protocol import case_agent, pending, run_case, run_cases
from dynplan.evaluation.replay import replay
from dynplan.evaluation.store import Run
from dynplan.evaluation.table import aggregate, load_results, render_markdown, write_table
from dynplan.logs import LogError, read_episode_log

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def eval_logs(tmp_path_factory):
    out = tmp_path_factory.mktemp("eval_logs")
    for i in range(2):
        record_episode(out, EVAL_SEED_START + i)
    return out


def test_cases_cover_the_table():
    all_cases = cases(["oracle", "zero", "random"], episodes=3)
    assert len(all_cases) == 3 * (2 * 4 + 2 * 4 + 2)
    assert {c.rollout_steps for c in all_cases if c.technique == "random"} == {None}
    assert all(c.seed >= EVAL_SEED_START for c in all_cases)
    with pytest.raises(ValueError, match="unknown technique 'magic'"):
        Case("magic", 1.0, 3, 0)


def test_table1_cases_are_the_committed_tables_rows():
    from dynplan.evaluation.cases import table1_cases

    groups = {(c.technique, c.model, c.agent_speed, c.rollout_steps) for c in table1_cases(episodes=2)}
    committed = json.loads((Path(__file__).parents[1] / "datasets/results/table1.json").read_text())
    assert groups == {(r["technique"], r["model"], r["agent_speed"], r["rollout_steps"]) for r in committed}
    assert len(table1_cases(episodes=2)) == 2 * len(groups)


def test_a_lockstep_batch_is_every_case_of_its_worlds_that_shares_a_world_model():
    from dynplan.evaluation.cases import table1_cases
    from dynplan.worlds.road.evaluate import batches

    todo = table1_cases(episodes=5)
    work = batches(todo, 2)
    assert sorted(map(repr, (c for b in work for c in b))) == sorted(map(repr, todo))  # each case once
    for batch in work:
        assert len({c.model for c in batch}) == 1 and len({c.seed for c in batch}) <= 2
    # 3 batches (2 + 2 + 1 worlds) per world model and for the techniques without one; a batch holds every
    # technique, speed and k of its worlds
    assert len(work) == 3 * 3 and {len({c.seed for c in b}) for b in work} == {1, 2}
    assert {(c.technique, c.agent_speed, c.rollout_steps) for c in work[3]} == {
        (c.technique, c.agent_speed, c.rollout_steps) for c in todo if c.model == work[3][0].model
    }


def test_run_case_writes_a_result_and_resumes(tmp_path, eval_logs):
    case, run = Case("oracle", 1.0, 3, EVAL_SEED_START), Run(tmp_path)
    record = run_case(case, eval_logs, run)
    path = run.episodes_path
    assert path.is_file() and record["outcome"] in {"goal", "timeout", "death"}
    assert len(record["decision_ms"]) == record["steps"] and record["code_version"].startswith("dynplan ")
    stamp = path.stat().st_mtime_ns
    assert run_case(case, eval_logs, run) == record
    assert path.stat().st_mtime_ns == stamp and run.rows() == [record]
    assert pending([case, Case("oracle", 1.0, 5, EVAL_SEED_START)], run, eval_logs) == [
        Case("oracle", 1.0, 5, EVAL_SEED_START)
    ]
    random = run_case(Case("random", 0.5, None, EVAL_SEED_START + 1), eval_logs, run)
    assert random["rollout_steps"] is None


def test_aggregate_counts_outcomes_and_steps_over_survivors():
    def result(outcome, steps, k=3):
        return {"technique": "oracle", "agent_speed": 1.0, "rollout_steps": k, "outcome": outcome, "steps": steps,
                "decision_ms": [1.0, 3.0], "wall_s": 0.5}  # fmt: skip

    rows = aggregate([result("goal", 10), result("goal", 30), result("timeout", 198), result("death", 5)])
    [row] = rows
    assert (row["episodes"], row["G"], row["T"], row["D"]) == (4, 2, 1, 1)
    assert row["S_mean"] == pytest.approx(np.mean([10, 30, 198]), abs=0.05)
    assert row["S_std"] == pytest.approx(np.std([10, 30, 198]), abs=0.05)
    assert row["decision_ms_median"] == 2.0
    table = render_markdown(rows)
    assert "| 2× oracle (ours) | " in table and "| 2× oracle (paper) | " in table
    assert "2/1/1, 79 ± 84" in table and "100/0/0, 36 ± 18" in table and "so far" not in table
    table = render_markdown(aggregate([result("goal", 10, k=1), result("goal", 12, k=1), result("goal", 20)]))
    assert "| 2/0/0, 11 ± 1 | 1/0/0, 20 ± 0 (of 1 so far) |" in table  # a case still being played says so


def test_evaluate_flow_plays_only_what_is_missing_and_writes_the_table(tmp_path, eval_logs, prefect_api):
    from dynplan.worlds.road.evaluate import RoadEvaluation
    from flows.worlds import evaluate_world

    def evaluate_planner(**kwargs):
        return evaluate_world("road", RoadEvaluation(**kwargs).model_dump(mode="json"), "python -m flows.evaluate")

    results = tmp_path / "results"
    plan = CasePlan(techniques=["oracle", "random"], agent_speeds=[1.0], rollout_steps=[1, 3], episodes=2)
    kwargs = dict(plan=plan, log_dir=str(eval_logs), results_dir=str(results))
    rows = evaluate_planner(**kwargs)
    assert {(r["technique"], r["rollout_steps"]) for r in rows} == {("oracle", 1), ("oracle", 3), ("random", None)}
    keys = {"technique", "agent_speed", "rollout_steps", "episodes", "G", "T", "D", "S_mean", "S_std",
            "decision_ms_median"}  # fmt: skip
    table = json.loads((results / "table1.json").read_text())
    assert all(keys <= set(row) for row in table) and all(row["episodes"] == 2 for row in table)
    run = Run(results)
    manifest = run.manifest()
    assert manifest["role"] == "evaluation" and manifest["episode_seeds"] == [EVAL_SEED_START, EVAL_SEED_START + 1]
    assert set(manifest["log_sha256"]) == {str(EVAL_SEED_START), str(EVAL_SEED_START + 1)}
    assert manifest["invocations"][0]["command"] == "python -m flows.evaluate"
    data = run.episodes_path.read_bytes()
    assert data.count(b"\n") == 6
    evaluate_planner(**kwargs)
    assert run.episodes_path.read_bytes() == data and len(run.manifest()["invocations"]) == 2
    assert len(load_results(results)) == 6
    write_table(rows, tmp_path / "again")
    assert (tmp_path / "again" / "table1.md").read_bytes() == (results / "table1.md").read_bytes()
    # a validation run is a run of its own, and Table 1 does not count it
    evaluate_planner(**{**kwargs, "plan": plan.model_copy(update={"rollout_steps": (1,)}), "run": "other"})
    assert Run(results, "other").manifest()["role"] == "candidate" and len(load_results(results)) == 6


def test_check_names_each_row_whose_recorded_episode_changed(tmp_path, eval_logs, prefect_api, capsys):
    """`flows.evaluate --check` plays nothing: each row's recorded episode is the one it was played on (a road row
    names its log by SHA-256), and a row whose log changed or went missing is named, exit 1."""
    from flows.evaluate import main

    logs = tmp_path / "logs"
    shutil.copytree(eval_logs, logs)
    argv = ["--techniques", "oracle", "--agent-speeds", "1.0", "--rollout-steps", "1", "--episodes", "2",
            "--playouts", "5", "--log-dir", str(logs), "--results-dir", str(tmp_path / "results"),
            "--run", "x"]  # fmt: skip
    played = main(argv)
    rows = Run(tmp_path / "results", "x").rows()
    assert main([*argv, "--check"]) == played and Run(tmp_path / "results", "x").rows() == rows  # nothing played
    assert capsys.readouterr().out.rstrip().endswith("every row of the run holds")
    log_path(logs, EVAL_SEED_START + 1).unlink()
    record_episode(logs, EVAL_SEED_START + 1, n_frames=300)  # another recording under the row's file name
    with pytest.raises(SystemExit) as stop:
        main([*argv, "--check"])
    (problem,) = capsys.readouterr().err.strip().splitlines()
    assert stop.value.code == 1 and f"technique=oracle seed={EVAL_SEED_START + 1}: log " in problem
    assert "the row was played on" in problem and Run(tmp_path / "results", "x").rows() == rows


def test_replay_round_trips_through_the_reader(tmp_path, eval_logs):
    log = log_path(eval_logs, EVAL_SEED_START)
    out, gif = tmp_path / "replay.mcap", tmp_path / "replay.gif"
    result = replay(log, AgentSpec(technique="oracle", rollout_steps=3), agent_speed=1.0, out=out, gif=gif)
    assert result.outcome in {"goal", "timeout", "death"} and result.steps >= 1
    recorded, replayed = read_episode_log(log), read_episode_log(out)
    np.testing.assert_array_equal(replayed.frames, recorded.frames[:203])
    assert replayed.agent is not None and len(replayed.agent.action) == result.steps
    assert replayed.agent.outcome[-1] == result.outcome and replayed.metadata["kind"] == "agent"
    np.testing.assert_array_equal(replayed.agent.t, np.arange(4, 5 + result.steps))
    t0 = int(replayed.agent.t[0])
    np.testing.assert_array_equal(replayed.imagined[t0], recorded.frames[t0 + 1 : t0 + 4])
    assert len(replayed.imagined) == result.steps
    assert Image.open(gif).n_frames == result.steps


def test_an_agent_spec_is_checked_whole_and_plays_any_technique():
    from dynplan.evaluation.protocol import plan_episode

    spec = AgentSpec(technique="model", model="paper", samples=2, rollout_steps=1, playouts=10, seed=2**40)
    assert spec.plans_with.samples == 2 and spec.own_caution.recorded() == {}
    assert plan_episode(EVAL_SEED_START, spec).outcome in {"goal", "timeout", "death"}  # a learned "model" too
    assert AgentSpec(technique="oracle", model="paper").model is None  # no world model, no configuration
    assert CasePlan(first_seed=2**40, episodes=2).cases()[-1].seed == 2**40 + 1
    for bad, message in [(dict(technique="oracle", caution={"occupancy": 2.0}), "occupancy=2.0 is invalid"),
                         (dict(technique="samples5", samples=3), "give them with technique 'model'"),
                         (dict(model="paper", caution={"occupancy": 0.1}), "'paper' has none"),
                         (dict(seed=-1), "seed=-1 is invalid")]:  # fmt: skip
        with pytest.raises(ConfigError, match=message):
            AgentSpec(**bad)
    plan = CasePlan(techniques=["random", "samples5", "oracle"], models=["default", "paper"])
    assert plan.pairs() == [("random", None), ("samples5", "default"), ("samples5", "paper"), ("oracle", None)]


def test_replay_errors(tmp_path, eval_logs):
    log = log_path(eval_logs, EVAL_SEED_START)
    with pytest.raises(LogError, match="missing.mcap: no such file"):
        replay(tmp_path / "missing.mcap")
    (tmp_path / "notes.mcap").write_text("hello")
    with pytest.raises(LogError, match="not an MCAP file"):
        replay(tmp_path / "notes.mcap")
    with pytest.raises(LogError, match="holds 407 frames; agent speed 0.25 needs 814"):
        replay(log, agent_speed=0.25)
    with pytest.raises(ConfigError, match="rollout_steps=0 is invalid"):
        AgentSpec(technique="oracle", rollout_steps=0)
    with pytest.raises(ConfigError, match="technique must be one of"):
        AgentSpec(technique="psychic")


@pytest.mark.slow
def test_replay_command_line(tmp_path, eval_logs):
    log = log_path(eval_logs, EVAL_SEED_START + 1)
    out = tmp_path / "r.mcap"
    proc = subprocess.run([sys.executable, "-m", "flows.replay", str(log), "--planner", "zero", "--json",
                           "--out", str(out)], cwd=ROOT, capture_output=True, text=True, timeout=300)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    assert result["outcome"] in {"goal", "timeout", "death"} and result["planner"] == "zero"
    assert {"steps", "decision_ms_median"} <= set(result) and out.is_file()
    for args, text in [([str(tmp_path / "nope.mcap")], "nope.mcap: no such episode log"),
                       ([str(log), "--rollout-steps", "0"], "--rollout-steps=0 is invalid; valid range [1, 64]"),
                       ([str(log), "--planner", "psychic"], "invalid choice: 'psychic'")]:  # fmt: skip
        bad = subprocess.run([sys.executable, "-m", "flows.replay", *args], cwd=ROOT, capture_output=True, text=True)
        assert bad.returncode == 2 and text in bad.stderr
        assert "Traceback" not in bad.stderr and text in bad.stderr.strip().splitlines()[-1]


def test_results_are_reused_only_for_the_same_playouts_and_log(tmp_path, eval_logs):
    case, run = Case("oracle", 1.0, 1, EVAL_SEED_START), Run(tmp_path)
    ten, twenty = AgentSpec(playouts=10), AgentSpec(playouts=20)
    first = run_case(case, eval_logs, run, ten)
    assert run_case(case, eval_logs, run, ten) == first
    assert pending([case], run, eval_logs, ten) == []
    assert pending([case], run, eval_logs, twenty) == [case]  # the flow replays what changed
    again = run_case(case, eval_logs, run, twenty)
    assert again["playouts"] == 20 and len(again["log_sha256"]) == 64
    with pytest.raises(ValueError, match="mix playouts values"):
        aggregate([first, again])


def test_the_search_never_looks_past_the_timeout_frame(eval_logs):
    from dynplan.planning.config import MCTSConfig
    from dynplan.planning.episode import run_episode
    from dynplan.planning.forward import ForwardModel, OracleModel
    from dynplan.planning.mcts import MCTSPlanner

    world = read_episode_log(log_path(eval_logs, EVAL_SEED_START)).world()
    oracle, asked = OracleModel(world), []

    class Spy(ForwardModel):
        name = "spy"

        def predict(self, observed, k):
            asked.append((len(observed) - 1, k))
            return oracle.predict(observed, k)

    # A 2× agent on a 407-frame recording: the oracle could show frames past 202, but must not be asked for them.
    result = run_episode(world, MCTSPlanner(MCTSConfig(rollout_steps=10, playouts=5), 1.0, 203), Spy(), 1.0, 10)
    assert all(t + k <= 202 for t, k in asked)
    if result.outcome == "timeout":
        assert asked[-1] == (201, 1)


def test_learned_techniques_run_per_world_model(tmp_path, eval_logs, monkeypatch):
    import torch

    import dynplan.evaluation.agent as agent_module
    import dynplan.models.world_model as world_model
    from dynplan.models.configs import PixelCNNConfig, VQVAEConfig
    from dynplan.models.pixelcnn import ConditionalPixelCNN
    from dynplan.models.registry import WORLD_MODELS
    from dynplan.models.vqvae import VQVAE

    torch.manual_seed(0)
    tokenizer = VQVAE(VQVAEConfig(channels=(8, 8), strides=(2, 2), latent_dim=4, codebook_size=16,
                                  likelihood="categorical", local=True))  # fmt: skip
    prior = ConditionalPixelCNN(PixelCNNConfig(codebook_size=16, channels=8, layers=2, condition_channels=8))
    monkeypatch.setattr(world_model, "world_model_parts", lambda paths, model: (tokenizer, prior))  # every caller's
    five = AgentSpec(playouts=5)
    all_cases = cases(["samples5", "oracle"], speeds=(1.0,), rollout_steps=(1,), episodes=1, models=("default",))
    assert [(c.technique, c.model) for c in all_cases] == [("samples5", "default"), ("oracle", None)]
    run = Run(tmp_path)
    records = [run_case(c, eval_logs, run, five) for c in all_cases]
    assert records[0]["world_model_sha256"] == "missing+missing" or "+" in records[0]["world_model_sha256"]
    assert records[0]["occupancy"] == WORLD_MODELS["default"].caution.occupancy > 0  # a result says its caution
    stale = {k: v for k, v in records[0].items() if k != "occupancy"}  # played before the threshold existed
    old = Run(tmp_path, "old")
    old.append(stale)
    assert pending(all_cases[:1], old, eval_logs, five) == [all_cases[0]]
    validated = AgentSpec(playouts=5, caution={"occupancy": 0.3})  # being validated
    other = run_case(all_cases[0], eval_logs, run, validated)
    assert other["occupancy"] == 0.3
    assert pending(all_cases, run, eval_logs, validated) == []
    assert pending(all_cases, run, eval_logs, AgentSpec(playouts=5, caution={"occupancy": 0.0})) == [all_cases[0]]
    assert pending(all_cases, run, eval_logs, five) == []  # each provenance's row is kept
    widened = run_case(all_cases[0], eval_logs, run, AgentSpec(playouts=5, caution={"occupancy": 0.3, "margin": 2}))
    assert (widened["occupancy"], widened["margin"]) == (0.3, 2)
    assert len(run.rows()) == 4
    devices = []  # the device reaches every learned model an evaluation builds, and is no part of provenance
    monkeypatch.setattr(world_model, "check_device", lambda name: devices.append(name) or name)
    monkeypatch.setattr(agent_module, "check_device", lambda name: name)
    assert run_cases(all_cases, eval_logs, run, AgentSpec(playouts=5, device="cuda:1")) == records  # played: found
    _, forward = case_agent(all_cases[0], read_episode_log(log_path(eval_logs, EVAL_SEED_START)).world(),
                            AgentSpec(device="cuda:1"))  # fmt: skip
    assert forward.device == "cuda:1" and devices == ["cuda:1"]
    rows = aggregate(records)
    assert {(r["technique"], r["model"]) for r in rows} == {("samples5", "default"), ("oracle", None)}
    assert "| 2× samples5 [default] (ours) | " in render_markdown(rows)
    with pytest.raises(ValueError, match="needs a world model"):
        Case("mid", 1.0, 3, 0)
    with pytest.raises(ValueError, match="does not use a world model"):
        Case("oracle", 1.0, 3, 0, "default")


def test_replay_with_the_learned_model_names_missing_checkpoints(eval_logs, tmp_path):
    from dynplan.models.checkpoint import CheckpointError

    with pytest.raises(CheckpointError, match=r"no world model checkpoints at .*paper/vqvae.pt"):
        agent = AgentSpec(technique="model", model="paper", model_dir=str(tmp_path))
        replay(log_path(eval_logs, EVAL_SEED_START), agent)


def test_replay_plans_with_the_committed_paper_world_model(eval_logs, tmp_path):
    from dynplan.models import pretrained_path

    if not pretrained_path("pixelcnn", "paper").exists():
        pytest.skip("no committed paper prior")
    agent = AgentSpec(technique="model", model="paper", samples=5, rollout_steps=1, playouts=20)
    result = replay(log_path(eval_logs, EVAL_SEED_START), agent, out=tmp_path / "replay.mcap")
    assert result.outcome in ("goal", "death", "timeout") and result.steps > 0
    replayed = read_episode_log(tmp_path / "replay.mcap")
    assert len(replayed.imagined) == result.steps and next(iter(replayed.imagined.values())).shape == (1, 48, 48)


def test_evaluate_command_line_names_a_bad_worker_count(capsys):
    from flows.evaluate import main

    with pytest.raises(SystemExit):
        main(["--workers", "0"])
    assert "--workers=0 is invalid; valid range [1, 256]" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (
            ["--occupancy", "1.5"],
            "--occupancy=1.5 is invalid; valid range [0.0, 1.0)",
        ),
        (
            ["--margin", "5"],
            "--margin=5 is invalid; valid range [0, 4]",
        ),
        (
            ["--occupancy", "0.1", "--techniques", "mid", "--models", "paper"],
            "occupancy=0.1 needs a tokenizer with patch-local codes (local=True); 'paper' has none",
        ),
        (["--first-seed", "2000000"], "--first-seed=2000000 needs its own --run"),
        (["--run", "../x"], "--run '../x' is not a run name"),
        (["--first-seed", "-1"], "seed"),
        (["--table1", "--techniques", "mid", "--agent-speeds", "0.5"], "drop --techniques --agent-speeds"),
        (["--device", "tpu"], "device='tpu' is invalid (value error, device must be a torch device"),
    ],
)
def test_evaluate_command_line_names_bad_validation_settings(argv, message, capsys):
    from flows.evaluate import main

    with pytest.raises(SystemExit):
        main(argv)
    assert message in capsys.readouterr().err
