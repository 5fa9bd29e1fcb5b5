"""The committed results store and weights are what they claim to be.

Learned rows took hours of evaluation: the committed Table 1 must be what the committed runs add up to (a fresh
clone has nothing else), every run's manifest must describe its rows, the evaluation must have been played with
the committed weights, and each model card must describe the weights beside it. The runs checked are the folders
of the store (`datasets/results/runs/*`), whatever they are."""

import hashlib
import io
import json
import re
from collections import defaultdict
from pathlib import Path

import pytest
import torch

from dynplan.evaluation.cases import EVAL_SEED_START, VALIDATION_SEED_START
from dynplan.evaluation.provenance import world_model_entry
from dynplan.evaluation.results import results_page
from dynplan.evaluation.store import ROLES, Run, case_key, expected_provenance
from dynplan.evaluation.table import aggregate, load_results, write_table

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "datasets" / "results"
WEIGHTS = ROOT / "dynplan" / "models" / "weights"
#: Every folder of the store's runs: one without a readable manifest fails, it is not skipped.
RUNS = sorted(p.name for p in (RESULTS / "runs").iterdir() if p.is_dir())
_SHA256 = re.compile(r"[0-9a-f]{64}(\+[0-9a-f]{64})*")


def test_the_store_holds_the_evaluation_run():
    assert "evaluation" in RUNS


@pytest.mark.parametrize("name", RUNS)
def test_a_runs_manifest_describes_its_episodes_and_how_they_were_played(name):
    manifest = Run(RESULTS, name).manifest()  # StoreError: missing, not JSON, or not a dynplan-run/1 manifest
    assert manifest["name"] == name and manifest["role"] in ROLES and manifest["playouts"] > 0
    seeds = manifest["episode_seeds"]
    assert seeds and seeds == sorted(set(seeds))
    # settings are chosen on the validation episodes, never on the evaluation's
    first = VALIDATION_SEED_START if manifest["role"] == "validation" else EVAL_SEED_START
    assert all(first <= s < first + 1_000_000 for s in seeds), (first, seeds[0], seeds[-1])
    assert set(manifest["log_sha256"]) == {str(s) for s in seeds} and all(manifest["log_sha256"].values())
    for model, entry in manifest["world_models"].items():
        assert _SHA256.fullmatch(entry["weights_sha256"]) and isinstance(entry.get("caution", {}), dict), model
    assert manifest["invocations"]
    assert all(i["command"].startswith("python -m ") and i["code_version"] for i in manifest["invocations"])


@pytest.mark.parametrize("name", RUNS)
def test_every_row_of_a_run_is_played_as_its_manifest_says_and_counts(name):
    run = Run(RESULTS, name)
    manifest, rows = run.manifest(), run.rows()
    assert rows, f"{name}: no episodes"
    for row in rows:
        expected = expected_provenance(manifest, row)
        assert {k: row.get(k) for k in expected} == expected, case_key(row)
        assert row["seed"] in manifest["episode_seeds"] and row["outcome"] in {"goal", "timeout", "death"}
        assert row["steps"] == len(row["decision_ms"]) > 0, case_key(row)
        assert row.get("model") is None or row["model"] in manifest["world_models"], case_key(row)
    assert len({case_key(r) for r in rows}) == len(rows), f"{name}: a case played twice (a stale row)"
    # what the store counts (Table 1, the results page, compare): every row, or its provenance rules drifted
    assert len(run.current()) == len(rows), f"{name}: the store counts {len(run.current())} of {len(rows)} rows"


@pytest.mark.parametrize("name", RUNS)
def test_a_run_plays_each_of_its_cases_on_every_seed(name):
    """Each (technique, model, speed, k) a run holds covers the manifest's seeds; only a superseded run may stop
    short (it stopped when its weights or settings were replaced; the results page says `of N`)."""
    run = Run(RESULTS, name)
    manifest = run.manifest()
    seeds: dict[tuple, set] = defaultdict(set)
    for row in run.rows():
        seeds[case_key(row)[:-1]].add(row["seed"])
    aggregate(run.rows())  # refuses a row of Table 1's shape that mixes provenance
    if manifest["role"] != "superseded":
        short = {case: len(s) for case, s in seeds.items() if s != set(manifest["episode_seeds"])}
        assert not short, f"{name}: cases short of the manifest's {len(manifest['episode_seeds'])} seeds: {short}"


def test_table1_is_what_the_evaluation_runs_add_up_to(tmp_path):
    """datasets/results/table1.{json,md}, byte for byte, from the evaluation runs."""
    json_path, md_path = write_table(aggregate(load_results(RESULTS)), tmp_path)
    assert json_path.read_bytes() == (RESULTS / "table1.json").read_bytes()
    assert md_path.read_bytes() == (RESULTS / "table1.md").read_bytes()


def test_the_results_page_is_what_its_command_writes():
    """docs/results.md is generated (`python -m dynplan.evaluation.results`), never edited by hand, and short."""
    page = (ROOT / "docs" / "results.md").read_text()
    assert page == results_page(RESULTS, ROOT / "docs")
    assert len(page.encode()) <= 22_000, "docs/results.md grew past 22 kB (Table 1, analyses, Freeway): summarise more"


def test_the_lab_runs_page_is_what_its_command_writes():
    """docs/runs.md is generated from the lab's store (`python -m lab.runs`), never edited by hand."""
    from lab.runs import LAB_RESULTS, TRAINING, runs_page

    assert (ROOT / "docs" / "runs.md").read_text() == runs_page(LAB_RESULTS, RESULTS, TRAINING)


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
TABLE_MARKER = "<!-- table1: generated from datasets/results/table1.json -->"


def _table_lines(text: str) -> list[str]:
    """The Markdown table rows of `text` (lines starting with '|'), in order."""
    return [line for line in text.splitlines() if line.startswith("|")]


def test_readme_table1_is_the_committed_tables_compact_form():
    """The README's Table 1 is the compact form of datasets/results/table1.json (`python -m
    dynplan.evaluation.results` writes both): every reported row's goals, timeouts and deaths, cell for cell."""
    from dynplan.evaluation.table import render_compact

    readme = README.read_text()
    assert TABLE_MARKER in readme, f"README.md lost its marker {TABLE_MARKER!r}"
    copied = _table_lines(readme.split(TABLE_MARKER, 1)[1].lstrip("\n").split("\n\n", 1)[0])
    rows = json.loads((RESULTS / "table1.json").read_text())
    assert copied == _table_lines(render_compact(rows)) and len(copied) > 2
    full = {(r["technique"], r["model"], r["agent_speed"], r["rollout_steps"]): r for r in rows}
    samples5 = full[("samples5", "default", 1.0, 3)]
    assert (
        "| 2× samples5 [default] | " in readme and f"{samples5['G']}/{samples5['T']}/{samples5['D']} (94/1/5)" in readme
    )


#: Committed rows replayed bit for bit: one per kind of technique and configuration (k = 1 keeps it quick).
REPLAYED = [("oracle", None, 1.0, 3), ("zero", None, 1.0, 3), ("random", None, 0.5, None),
            ("mid", "default", 1.0, 1), ("samples5", "default", 1.0, 1), ("futures5", "default", 1.0, 1),
            ("samples5", "paper", 1.0, 1)]  # fmt: skip


@pytest.mark.slow
def test_replaying_committed_rows_reproduces_their_outcomes(tmp_path):
    """The committed evaluation replays exactly: same outcome and steps for the same case, log, weights and
    caution (what any refactor of the planner, the world model or the protocol must keep)."""
    from dynplan.data.collect import record_episode
    from dynplan.evaluation.cases import Case
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
    """A candidate prior's record (docs/design.md §3.3) names its weights by hash, and its last epoch is its
    metrics'. Weights in the tree are the exported checkpoint of the record's config; weights not adopted were
    taken out of the tree, and the record says at which commit they are."""
    info, folder = json.loads(record.read_text()), record.parent
    last = (folder / "metrics.csv").read_text().strip().splitlines()[-1].split(",")
    assert (int(last[0]), int(last[1])) == (info["epochs"], info["windows_seen"]) and info["commands"]
    assert re.fullmatch(r"[0-9a-f]{64}", info["sha256"])
    weights = folder / info["weights"]
    if info.get("weights_in_tree", True) is False:
        assert not weights.exists() and re.fullmatch(r"[0-9a-f]{40}", info["weights_commit"])
        assert info["weights_commit"][:8] in info["weights_note"]
        return
    data = weights.read_bytes()
    assert info["sha256"] == hashlib.sha256(data).hexdigest()
    checkpoint = torch.load(io.BytesIO(data), map_location="cpu", weights_only=False)
    assert checkpoint["kind"] == info["stage"]
    assert checkpoint["config"] == json.loads((folder / "config.json").read_text())


FREEWAY_RESULTS = ROOT / "datasets" / "results" / "freeway"


def _freeway_rows() -> list[dict]:
    from dynplan.worlds.freeway.evaluation import read_run

    return read_run(FREEWAY_RESULTS, "evaluation")


def test_freeways_committed_run_is_the_evaluation_it_names_played_with_the_committed_weights():
    """Every (technique, mode, episode) of the committed evaluation, once, each learned row by the committed weights,
    each with one action a step; the manifest names the world, the emulator's settings and the command."""
    pytest.importorskip("ale_py")
    from dynplan.worlds.freeway.evaluation import EVALUATION_COMMAND, TECHNIQUES, FreewayPlan
    from dynplan.worlds.freeway.results import RUNS, SETTINGS, decode_actions, weights_entry

    manifest = Run(FREEWAY_RESULTS, "evaluation", RUNS).manifest()
    assert manifest["world"] == "freeway-v1" and manifest["settings"] == SETTINGS and manifest["role"] == "evaluation"
    assert manifest["world_models"]["freeway"]["weights_sha256"] == weights_entry("freeway", None)["weights_sha256"]
    assert manifest["invocations"][0]["command"] == EVALUATION_COMMAND
    rows = _freeway_rows()
    cases = {(r["technique"], r["mode"], r["episode"]) for r in rows}
    assert cases == {(t, m, i) for t in TECHNIQUES for m in (0, 4) for i in range(20)} and len(rows) == len(cases)
    for row in rows:
        assert row["noop_start"] == FreewayPlan(mode=row["mode"], episodes=20).episode_list()[row["episode"]].noop_start
        assert len(decode_actions(row["actions"])) == row["steps"] == 2048 - row["noop_start"]


def test_freeway_rows_replay_to_their_scores_in_a_fresh_emulator():
    """A sample of the committed rows (one per technique and mode): their actions give their score, knocks and steps
    on the real game (the whole run: `python -m flows.evaluate --world freeway --check`, below)."""
    pytest.importorskip("ale_py")
    from dynplan.worlds.freeway.results import replay_check

    sample = {(r["technique"], r["mode"]): r for r in _freeway_rows()}
    assert len(sample) == 12
    for row in sample.values():
        assert replay_check(row) is None, (row["technique"], row["mode"], row["episode"])


def test_freeways_sticky_run_plays_the_same_episodes_with_sticky_actions_and_replays_with_them():
    """The run `sticky`: the evaluation's episodes of the planning techniques with the game's sticky actions (its
    settings), each once; a sample (one per technique and mode) replays with those settings, not without them."""
    pytest.importorskip("ale_py")
    from dynplan.worlds.freeway.results import RUNS, SETTINGS, replay_check, settings

    run = Run(FREEWAY_RESULTS, "sticky", RUNS)
    manifest, rows = run.manifest(), run.current()
    assert manifest["settings"] == settings(0.25) and manifest["role"] == "evaluation"
    played = [invocation["command"] for invocation in manifest["invocations"]]
    assert all(c.startswith("python -m flows.evaluate --world freeway --run sticky --techniques") for c in played)
    cases = {(r["technique"], r["mode"], r["episode"]) for r in rows}
    techniques = ("oracle", "learned", "extrapolate", "zero")
    assert cases == {(t, m, i) for t in techniques for m in (0, 4) for i in range(20)} and len(rows) == len(cases)
    sample = {(r["technique"], r["mode"]): r for r in rows}
    for row in sample.values():
        assert replay_check(row, settings(0.25)) is None, (row["technique"], row["mode"], row["episode"])
    assert any(replay_check(row, SETTINGS) is not None for row in sample.values())


@pytest.mark.slow
@pytest.mark.parametrize("run", ["evaluation", "sticky"])
def test_every_committed_freeway_score_holds_when_its_actions_are_replayed(run):
    pytest.importorskip("ale_py")
    import subprocess
    import sys

    command = [sys.executable, "-m", "flows.evaluate", "--world", "freeway", "--run", run, "--check"]
    done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=1800)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "every row of the run holds" in done.stdout


def test_freeways_check_names_a_row_whose_actions_do_not_give_its_score(tmp_path):
    """`flows.evaluate --world freeway --check` (the rows replayed on every core): a row told one point more than
    its actions score is named, the others hold."""
    pytest.importorskip("ale_py")
    from dynplan.worlds.freeway.commands import Evaluate, FreewayEvaluation
    from dynplan.worlds.freeway.results import RUNS

    rows = Run(FREEWAY_RESULTS, "sticky", RUNS).current()
    picked = [r for r in rows if r["technique"] == "zero" and r["mode"] == 0][:3]
    picked[1] = {**picked[1], "score": picked[1]["score"] + 1}
    run_dir = tmp_path / "runs" / "sticky"
    run_dir.mkdir(parents=True)
    (run_dir / "manifest.json").write_text((FREEWAY_RESULTS / "runs" / "sticky" / "manifest.json").read_text())
    (run_dir / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in picked))
    problems = Evaluate().check(FreewayEvaluation(results=str(tmp_path), run="sticky", role="evaluation"))
    assert len(problems) == 1 and f"episode={picked[1]['episode']}" in problems[0], problems
    assert problems[0].startswith(f"{run_dir / 'episodes.jsonl'}:2: technique=zero "), problems  # the file and line
