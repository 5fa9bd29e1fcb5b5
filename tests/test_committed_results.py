"""The committed results store and weights are what they claim to be.

Learned rows took hours of evaluation: the committed Table 1 must be what the committed runs add up to (a fresh
clone has nothing else), every run's manifest must describe its rows, the evaluation must have been played with
the committed weights, and each model card must describe the weights beside it."""

import hashlib
import io
import json
from pathlib import Path

import pytest
import torch

from dynplan.evaluation.provenance import world_model_entry
from dynplan.evaluation.results import results_page
from dynplan.evaluation.store import ROLES, Run, expected_provenance, runs
from dynplan.evaluation.table import aggregate, load_results, render_markdown

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "datasets" / "results"
WEIGHTS = ROOT / "dynplan" / "models" / "weights"
#: Rows per committed run, as imported from the per-episode result files they replace: nothing may go missing.
COMMITTED_ROWS = {
    "evaluation": 5800, "validation": 500, "validation_margin1": 300, "validation_paper_annealed": 200,
    "validation_paper_continued": 200, "validation_paper_margin1": 200, "validation_paper_margin2": 200,
    "validation_paper_margin3": 200, "candidate_paper_annealed": 1200, "candidate_paper_margin2": 500,
    "default_margin0": 1931, "default_epoch7": 1970, "validation_context8": 300, "validation_speed05": 400,
    "validation_speed05_context8": 400, "validation_context16": 300, "validation_speed05_context16": 400,
    "validation_marginal8": 300, "validation_speed05_marginal8": 300, "validation_speed05_marginal16": 200,
    "validation_speed05_oracle": 400, "validation_speed05_span1": 300, "validation_speed05_span2": 300,
    "validation_span1": 300,
}  # fmt: skip


def test_every_committed_run_is_present_whole():
    counts = {run.name: len(run.current()) for run in runs(RESULTS)}
    assert {name: counts.get(name) for name in COMMITTED_ROWS} == COMMITTED_ROWS


@pytest.mark.parametrize("name", sorted(COMMITTED_ROWS))
def test_a_runs_rows_all_match_its_manifest(name):
    run = Run(RESULTS, name)
    manifest = run.manifest()
    assert manifest["role"] in ROLES and manifest["invocations"]
    rows = run.rows()
    assert all(
        {k: r.get(k) for k in expected_provenance(manifest, r)} == expected_provenance(manifest, r) for r in rows
    )
    seeds = {r["seed"] for r in rows}
    assert seeds <= set(manifest["episode_seeds"]) and len(aggregate(rows)) > 0  # aggregation refuses a mixed row


def test_table1_is_what_the_evaluation_runs_add_up_to():
    assert json.loads((RESULTS / "table1.json").read_text()) == aggregate(load_results(RESULTS))


def test_the_results_page_is_what_its_command_writes():
    """docs/results.md is generated (`python -m dynplan.evaluation.results`), never edited by hand."""
    assert (ROOT / "docs" / "results.md").read_text() == results_page(RESULTS, ROOT / "docs")
    table = (RESULTS / "table1.md").read_text()
    assert render_markdown(aggregate(load_results(RESULTS))) in table


def test_the_evaluation_was_played_with_the_committed_weights():
    manifest = Run(RESULTS).manifest()
    for model, entry in manifest["world_models"].items():
        committed = world_model_entry(model)
        assert entry["weights_sha256"] == committed["weights_sha256"], f"{model}: retrain? replay the evaluation"
        assert entry["caution"] == committed["caution"]


@pytest.mark.parametrize("card", sorted(WEIGHTS.glob("*.json")), ids=lambda p: p.stem)
def test_model_cards_describe_their_weights(card):
    info = json.loads(card.read_text())
    weights = WEIGHTS / info["weights"]
    data = weights.read_bytes()
    assert info["sha256"] == hashlib.sha256(data).hexdigest() and info["bytes"] == len(data)
    checkpoint = torch.load(weights, map_location="cpu", weights_only=False)
    assert checkpoint["kind"] == info["stage"] and checkpoint["config"]["name"] == info["configuration"]
    assert info["parameters"] == sum(t.numel() for t in checkpoint["model"].values())
    assert {k: v for k, v in checkpoint["config"].items() if k in info["config"]} == {
        k: tuple(v) if isinstance(v, list) else v for k, v in info["config"].items()
    }
    assert info["held_out"] and info["commands"] and (ROOT / info["documentation"] / "metrics.csv").is_file()
    assert len(list(WEIGHTS.glob("*.pt"))) == len(list(WEIGHTS.glob("*.json")))


README = ROOT / "README.md"
TABLE_MARKER = "<!-- table1: generated from datasets/results/table1.md -->"


def _table_lines(text: str) -> list[str]:
    """The Markdown table rows of `text` (lines starting with '|'), in order."""
    return [line for line in text.splitlines() if line.startswith("|")]


def test_readme_table1_is_the_committed_table():
    """The README's Table 1 is datasets/results/table1.md's (`python -m dynplan.evaluation.results` writes both)."""
    readme = README.read_text()
    assert TABLE_MARKER in readme, f"README.md lost its marker {TABLE_MARKER!r}"
    copied = readme.split(TABLE_MARKER, 1)[1].lstrip("\n").split("\n\n", 1)[0]
    committed = _table_lines((RESULTS / "table1.md").read_text())
    assert len(committed) > 2, "datasets/results/table1.md has no rows"
    assert _table_lines(copied) == committed


#: Committed rows replayed bit for bit: one per kind of technique and configuration (k = 1 keeps it quick).
REPLAYED = [("oracle", None, 1.0, 3), ("zero", None, 1.0, 3), ("random", None, 0.5, None),
            ("mid", "default", 1.0, 1), ("samples5", "default", 1.0, 1), ("futures5", "default", 1.0, 1),
            ("samples5", "paper", 1.0, 1)]  # fmt: skip


@pytest.mark.slow
def test_replaying_committed_rows_reproduces_their_outcomes(tmp_path):
    """The committed evaluation replays exactly: same outcome and steps for the same case, log, weights and
    caution (what any refactor of the planner, the world model or the protocol must keep)."""
    from dynplan.data.collect import record_episode
    from dynplan.evaluation.cases import EVAL_SEED_START, Case
    from dynplan.evaluation.protocol import run_case

    seeds = [EVAL_SEED_START, EVAL_SEED_START + 1]
    for seed in seeds:
        record_episode(tmp_path / "logs", seed)
    committed = {(r["technique"], r["model"], r["agent_speed"], r["rollout_steps"], r["seed"]): r
                 for r in Run(RESULTS).current()}  # fmt: skip
    for technique, model, speed, k in REPLAYED:
        for seed in seeds:
            row = committed[(technique, model, speed, k, seed)]
            again = run_case(Case(technique, speed, k, seed, model), tmp_path / "logs", Run(tmp_path / "store"))
            assert again["log_sha256"] == row["log_sha256"] and again.get("world_model_sha256") == row.get(
                "world_model_sha256"
            )
            assert (again["outcome"], again["steps"]) == (row["outcome"], row["steps"]), (technique, model, k, seed)


@pytest.mark.parametrize("record", sorted((ROOT / "datasets" / "training").glob("*/provenance.json")),
                         ids=lambda p: p.parent.name)  # fmt: skip
def test_candidate_records_describe_their_weights(record):
    """A candidate prior's record (docs/design.md §3.3) names its weights by hash, and its config and last epoch
    are the exported checkpoint's and its metrics'."""
    info, folder = json.loads(record.read_text()), record.parent
    data = (folder / info["weights"]).read_bytes()
    assert info["sha256"] == hashlib.sha256(data).hexdigest()
    checkpoint = torch.load(io.BytesIO(data), map_location="cpu", weights_only=False)
    assert checkpoint["kind"] == info["stage"]
    assert checkpoint["config"] == json.loads((folder / "config.json").read_text())
    last = (folder / "metrics.csv").read_text().strip().splitlines()[-1].split(",")
    assert (int(last[0]), int(last[1])) == (info["epochs"], info["windows_seen"])
