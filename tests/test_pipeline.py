"""The collect-train-eval pipeline: presets, an end-to-end run that a rerun serves from its caches, the Prefect
deployment against a real server, and the same run on a real Dask cluster."""

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from dynplan.config import ConfigError
from dynplan.evaluation.store import Run
from dynplan.pipeline.presets import ROAD_PRESETS, EvalPlan, PipelinePreset, pipeline_preset
from dynplan.worlds.freeway.presets import FreewayEvalPlan


def test_presets_are_valid_data():
    quick, full = ROAD_PRESETS["quick"], ROAD_PRESETS["full"]
    assert quick.pixelcnn_config("default").codebook_size == quick.vqvae_config("default").codebook_size
    assert full.models == ("default", "paper") and full.pretrained and full.evaluation.episodes == 100
    assert set(full.evaluation.techniques) >= {"oracle", "mid", "samples5", "samples10"}
    assert quick.learned_techniques == ("mid",)
    with pytest.raises(ConfigError, match="unknown techniques"):
        EvalPlan(techniques=("oracle", "psychic"))
    with pytest.raises(ConfigError, match=r"train_episodes=2 is invalid.*valid range \[5, 1000000\]"):
        PipelinePreset(name="x", train_episodes=2)
    with pytest.raises(ConfigError, match="codebook_size"):
        PipelinePreset(name="x", train_episodes=5, vqvae={"default": {"overrides": {"codebook_size": 1}}})


def test_freeway_presets_are_valid_data():
    quick, full = pipeline_preset("quick", "freeway"), pipeline_preset("full", "freeway")
    assert quick.folder == "freeway-quick" and quick.models == ("freeway",) and quick.train_episodes == 8
    assert quick.learned_techniques == ("learned",) and quick.evaluation.modes == (0,)
    assert quick.pixelcnn_config("freeway").strip_rows == 4 and quick.vqvae_config("freeway").world == "freeway"
    assert full.pretrained and full.evaluation.modes == (0, 4) and full.evaluation.episodes == 20
    assert PipelinePreset(**quick.model_dump(mode="json")) == quick  # the flow's tasks rebuild it from JSON
    with pytest.raises(ConfigError, match="unknown techniques"):
        FreewayEvalPlan(techniques=("oracle", "mid"))
    with pytest.raises(ConfigError, match=r"mode=9 is invalid.*valid range \[0, 7\]"):
        FreewayEvalPlan(modes=(0, 9))
    with pytest.raises(ConfigError, match=r"train_episodes=9 is invalid for the freeway world; valid range \[5, 8\]"):
        PipelinePreset(name="x", world="freeway", train_episodes=9, models=("freeway",), evaluation=FreewayEvalPlan())
    with pytest.raises(ConfigError, match="the evaluation plays the road world, not this run's freeway"):
        PipelinePreset(name="x", world="freeway", train_episodes=8, models=("freeway",), evaluation=EvalPlan())
    # an evaluation without its world, or none, is the run's world's
    default = PipelinePreset(name="x", world="freeway", train_episodes=8, models=("freeway",))
    assert default.evaluation == FreewayEvalPlan()
    given = PipelinePreset(name="x", world="freeway", train_episodes=8, models=("freeway",), evaluation={"modes": [4]})
    assert given.evaluation == FreewayEvalPlan(modes=(4,))
    with pytest.raises(ConfigError, match="world 'mars' is not one of road, freeway"):
        PipelinePreset(name="x", world="mars", train_episodes=8)
    with pytest.raises(ConfigError, match="models must be among"):
        PipelinePreset(name="x", world="freeway", train_episodes=8, evaluation=FreewayEvalPlan())
    with pytest.raises(ValueError, match="preset must be one of"):
        pipeline_preset("huge", "freeway")


def test_freeway_runs_are_named_by_the_weights_the_learned_agent_reads(tmp_path):
    from dynplan.worlds.freeway.report import REFERENCE_RUN, run_of, weights_run

    for stage in ("vqvae", "pixelcnn"):
        (tmp_path / f"{stage}.pt").write_bytes(stage.encode())
    first = weights_run(tmp_path)
    assert run_of("learned", tmp_path) == first and first.startswith("weights-")
    assert {run_of(t, tmp_path) for t in ("oracle", "zero", "up", "random")} == {REFERENCE_RUN}
    (tmp_path / "pixelcnn.pt").write_bytes(b"retrained")
    assert weights_run(tmp_path) != first  # new weights play anew


def test_cli_rejects_an_unknown_preset():
    result = subprocess.run([sys.executable, "-m", "flows.collect_train_eval", "--preset", "huge"],
                            capture_output=True, text=True)  # fmt: skip
    assert result.returncode == 2 and "invalid choice: 'huge'" in result.stderr


def _files(folder):
    return {p: p.stat().st_mtime_ns for p in folder.rglob("*") if p.is_file()}


@pytest.mark.slow
def test_end_to_end_run_writes_the_report_and_reruns_from_cache(tmp_path, prefect_api):
    from flows.collect_train_eval import collect_train_eval

    report = collect_train_eval(preset="smoke", out=str(tmp_path))
    work = tmp_path / "smoke"
    text = (work / "report" / "report.md").read_text()
    assert report == str(work / "report" / "report.md")
    for section in ("## Table 1", "| 2× oracle (ours) |", "| 2× mid [default] (ours) |", "![figure 1](figure1.png)",
                    "| vqvae [default] |", "### pixelcnn `default`", '"codebook_size": 16',
                    "show that every stage works; they are not the paper's figures"):  # fmt: skip
        assert section in text, section
    assert "<table>" in (work / "report" / "report.html").read_text()
    for picture in ("prediction_error.png", "figure1.png", "episode.gif"):
        assert (work / "report" / picture).stat().st_size > 1000
    run = Run(work / "results")
    assert len(run.rows()) == 2 and run.manifest()["role"] == "evaluation"  # oracle and mid, one episode each
    before = (
        _files(work / "checkpoints") | _files(work / "models") | {run.episodes_path: run.episodes_path.read_bytes()}
    )

    collect_train_eval(preset="smoke", out=str(tmp_path))
    after = _files(work / "checkpoints") | _files(work / "models") | {run.episodes_path: run.episodes_path.read_bytes()}
    assert after == before  # nothing retrained, reinstalled or replayed
    rerun = (work / "report" / "report.md").read_text()
    assert "| vqvae [default] | " in rerun and "cached, 1 epochs" in rerun and "0 recorded now" in rerun
    # The Prefect UI's view: both runs' Table 1 and report under one key each, progress of the first run's work
    from flows.artifacts import read_artifacts as artifacts

    tables, reports = artifacts(key="table1-smoke"), artifacts(key="report-smoke")
    assert len(tables) == len(reports) == 2 and {a.type for a in tables + reports} == {"table", "markdown"}
    cells = {(row["technique"], row["model"]): row for row in json.loads(tables[-1].data)}
    assert cells[("oracle", None)]["episodes"] == cells[("mid", "default")]["episodes"] == 1
    assert "| 2× mid [default] (ours) |" in tables[-1].description and "## Table 1" in reports[-1].data
    progress = [a for a in artifacts(kind="progress") if a.data == 100.0]
    described = " ".join(a.description for a in progress)
    assert "episodes played into run 'evaluation': 2 of 2" in described and "epochs of vqvae-default" in described


@pytest.mark.slow
@pytest.mark.parametrize(("deployment", "section"), [("smoke", "## Table 1"), ("freeway-smoke", "| up | 2")])
def test_deployment_runs_on_a_real_prefect_server(tmp_path, deployment, section):
    from dynplan.pipeline.deployment_check import run_check

    if deployment.startswith("freeway"):
        pytest.importorskip("ale_py")
    report = run_check(tmp_path, deployment)
    assert section in report.read_text()
    assert "Completed" in (tmp_path / "trigger.log").read_text()


@pytest.mark.slow
def test_pipeline_on_a_dask_cluster_equals_a_local_run(tmp_path, dask_cluster, prefect_api):
    from flows.collect_train_eval import collect_train_eval

    cluster, local = tmp_path / "cluster", tmp_path / "local"
    collect_train_eval(preset="smoke", out=str(cluster), dask_address=dask_cluster.address)
    collect_train_eval(preset="smoke", out=str(local))
    worker_logs = "".join(p.read_text() for p in dask_cluster.logs.glob("worker*.log"))
    assert "Task run 'play-world-job" in worker_logs and "Task run 'inspect-log" in worker_logs

    def outcomes(root):
        return {(r["technique"], r["model"], r["seed"]): (r["outcome"], r["steps"], r["log_sha256"])
                for r in Run(root / "smoke" / "results").rows()}  # fmt: skip

    assert outcomes(cluster) == outcomes(local) and len(outcomes(local)) == 2
    for name in ("vqvae.pt", "pixelcnn.pt"):  # trained locally in both: the same weights from the same data
        a, b = (torch.load(root / "smoke" / "models" / "default" / name, weights_only=False)["model"]
                for root in (cluster, local))  # fmt: skip
        assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


def test_the_readme_main_command_is_the_pipeline():
    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    main = next(line for line in readme.splitlines() if line.startswith("python3 -m venv .venv && "))
    command = main.split("#")[0].rstrip()  # its time after the comment sign
    assert command.endswith(".venv/bin/python -m flows.collect_train_eval")  # quick preset, ephemeral API, datasets/


@pytest.mark.slow
def test_cli_runs_the_pipeline_on_an_ephemeral_api(tmp_path):
    import os

    no_api = {k: v for k, v in os.environ.items() if k != "PREFECT_API_URL"}  # its own temporary API

    def run() -> tuple[subprocess.CompletedProcess, list[str]]:
        result = subprocess.run([sys.executable, "-m", "flows.collect_train_eval", "--preset", "smoke", "--out",
                                 str(tmp_path)], capture_output=True, text=True, timeout=600,
                                env={**no_api, "PREFECT_HOME": str(tmp_path / "prefect")})  # fmt: skip
        assert result.returncode == 0, result.stderr[-3000:]
        return result, (result.stdout + result.stderr).strip().splitlines()

    result, lines = run()
    report = json.loads(result.stdout.strip().splitlines()[-1])["report"]
    assert report == str(tmp_path / "smoke" / "report" / "report.md")
    assert "--preset smoke" in Path(report).read_text()  # the report names the command that regenerates it
    # the console: a line a stage, none of Prefect's own run lines (those are --verbose's)
    assert [s.split(":")[0] for s in _stages(lines)] == ["collect", "build datasets", "vqvae [default]",
                                                         "pixelcnn [default]", "evaluate"], lines  # fmt: skip
    assert len(lines) <= 40 and not any("Finished in state" in line for line in lines), lines
    _, again = run()  # a rerun: every stage says it was cached
    assert len(again) <= 15 and all("cached" in s for s in _stages(again)[:4]), again
    assert any("every episode already played" in line for line in again), again


def _stages(lines: list[str]) -> list[str]:
    """The pipeline's stage lines, from the stage's name on."""
    return [line.split(" - stage ", 1)[1] for line in lines if " - stage " in line]


@pytest.mark.slow
def test_pretrained_run_uses_the_committed_tokenizer_and_trains_its_prior(tmp_path, prefect_api, monkeypatch):
    from dynplan.files import sha256_file
    from dynplan.models import pretrained_path
    from flows import collect_train_eval as pipeline

    smoke = ROAD_PRESETS["smoke"]
    monkeypatch.setitem(ROAD_PRESETS, "smoke", smoke.model_copy(update={"pretrained": True}))
    monkeypatch.setattr(pipeline, "pretrained_path", lambda stage, model: (
        pretrained_path(stage, model) if stage == "vqvae" else tmp_path / "no-such-prior.pt"))  # fmt: skip
    pipeline.collect_train_eval(preset="smoke", out=str(tmp_path))
    models = tmp_path / "smoke" / "models" / "default"
    assert sha256_file(models / "vqvae.pt") == sha256_file(pretrained_path("vqvae", "default"))
    prior = torch.load(models / "pixelcnn.pt", weights_only=False)
    assert prior["config"]["codebook_size"] == 4096 and prior["config"]["channels"] == 8  # K from the tokenizer
    assert "| vqvae [default] | " in (tmp_path / "smoke" / "report" / "report.md").read_text()


@pytest.mark.slow
def test_freeway_run_writes_its_report_and_reruns_from_cache(tmp_path, prefect_api):
    pytest.importorskip("ale_py")
    from flows.collect_train_eval import collect_train_eval

    report = collect_train_eval(preset="smoke", out=str(tmp_path), world="freeway")
    work = tmp_path / "freeway-smoke"
    text = Path(report).read_text()
    assert report == str(work / "report" / "report.md")
    for section in ("freeway preset `smoke`", "## Atari Freeway", "--world freeway --preset smoke",
                    "| vqvae [freeway] |", "### pixelcnn `freeway`", "6 episodes, 6 recorded now"):  # fmt: skip
        assert section in text, section
    assert re.search(r"\| up \| 2\d ± 0, \d+ \|  \|", text)  # always-UP scores 21–23, depending on the NOOP start
    runs = [p.name for p in (work / "results" / "runs").iterdir() if p.is_dir()]
    assert runs == ["reference"]  # always-UP does not read the weights
    played = work / "results" / "runs" / "reference" / "episodes.jsonl"
    row = json.loads(played.read_text())
    assert row["actions"] == f"U{row['steps']}" and row["steps"] == 2048 - row["noop_start"]
    before = _files(work / "checkpoints") | _files(work / "models") | {played: played.stat().st_mtime_ns}

    collect_train_eval(preset="smoke", out=str(tmp_path), world="freeway")
    after = _files(work / "checkpoints") | _files(work / "models") | {played: played.stat().st_mtime_ns}
    assert after == before  # nothing trained or played again
    rerun = (work / "report" / "report.md").read_text()
    assert "cached, 1 epochs" in rerun and "0 recorded now" in rerun and "6 episodes: 0 added" in rerun
