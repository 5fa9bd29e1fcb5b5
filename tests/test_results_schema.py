"""The results store's schema and the pages that never lose what they show, on copies of the committed store.

Each damage is real: a committed run copied into a temporary store, one line or field of it changed the way a bad
edit, a script writing strings or a second run pasted in would change it. Every refusal is one line naming the
file and the line (or the page and what it would lose), and the committed files are never touched."""

import json
import math
import shutil
import warnings
from pathlib import Path

import pytest

import dynplan.evaluation.results as results_module
from dynplan.evaluation.compare import main as compare_main
from dynplan.evaluation.results import lost_entries, page_entries
from dynplan.evaluation.store import Run, StoreError, TornRowWarning, check_store, runs
from dynplan.evaluation.table import aggregate, load_results

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "datasets" / "results"
#: The lab's store: the validation and candidate runs (docs/runs.md).
LAB_RESULTS = ROOT / "lab" / "results"
#: A small committed run of the lab's (200 rows), copied for the damage tests.
SMALL = "validation_paper_margin1"
COMMAND = "python -m dynplan.evaluation.results"


def small_run(tmp_path: Path) -> Run:
    shutil.copytree(LAB_RESULTS / "runs" / SMALL, tmp_path / "runs" / SMALL)
    return Run(tmp_path, SMALL)


def edit_row(run: Run, number: int, change) -> None:
    """Rewrite line `number` of the run's episodes with `change(row)` (a dict, or the new line's text)."""
    lines = run.episodes_path.read_text().splitlines(keepends=True)
    new = change(json.loads(lines[number - 1]))
    lines[number - 1] = (new if isinstance(new, str) else json.dumps(new, separators=(",", ":"))) + "\n"
    run.episodes_path.write_text("".join(lines))


def _set(key, value):
    return lambda row: {**row, key: value}


def _without(key):
    return lambda row: {k: v for k, v in row.items() if k != key}


ROW_DAMAGE = {
    "steps as a string": (_set("steps", "abc"), "field 'steps' = 'abc' is not an integer"),
    "unknown outcome": (_set("outcome", "win"), "field 'outcome' = 'win' is not one of 'goal', 'timeout' or 'death'"),
    "negative seed": (_set("seed", -5), "field 'seed' = -5 is out of range (should be greater than or equal to 0)"),
    "speed as a string": (_set("agent_speed", "1.0"), "field 'agent_speed' = '1.0' is not a number"),
    "a decision time as a string": (lambda row: {**row, "decision_ms": [1.0, 2.0, "x"]},
                                    "field 'decision_ms' has item 2 = 'x', not a finite number ≥ 0"),
    "no outcome": (_without("outcome"), "field 'outcome' is missing"),
    "no playouts": (_set("playouts", 0), "field 'playouts' = 0 is out of range (should be greater than or equal to 1)"),
    "wall time NaN": (lambda row: json.dumps({**row, "wall_s": math.nan}, separators=(",", ":")),
                      "field 'wall_s' = nan is not a finite number"),
    "occupancy of 1.5": (_set("occupancy", 1.5), "field 'occupancy' = 1.5 is out of range (should be less than 1)"),
    "a nested setting": (_set("span", {"lanes": 1}), "field 'span' is not a setting"),
    "an array": (lambda row: "[1, 2]", "not a JSON row (not a JSON object)"),
    "steps of 10**30": (lambda row: {**row, "steps": 10**30, "decision_ms": [1.0]},
                        f"the record holds 1 decision times for its {10**30} steps"),
}  # fmt: skip


@pytest.mark.parametrize("damage", ROW_DAMAGE, ids=list(ROW_DAMAGE))
def test_a_row_that_breaks_the_schema_names_the_file_the_line_and_the_field(tmp_path, damage):
    change, message = ROW_DAMAGE[damage]
    run = small_run(tmp_path)
    edit_row(run, 17, change)
    with pytest.raises(StoreError) as caught:
        run.rows()
    text = str(caught.value)
    assert f"runs/{SMALL}/episodes.jsonl:17: {message}" in text and "\n" not in text
    damaged = run.episodes_path.read_bytes()
    with pytest.raises(StoreError, match=r"episodes.jsonl:17: "):  # nothing is appended to it either
        run.append({**Run(LAB_RESULTS, SMALL).rows()[0], "seed": 2000100})
    assert run.episodes_path.read_bytes() == damaged


@pytest.mark.parametrize("line", [b"\xff\xfe{}", b"[" * 100_000], ids=["not UTF-8", "nested too deeply"])
def test_an_unreadable_line_is_damage_not_a_traceback(tmp_path, line):
    run = small_run(tmp_path)
    lines = run.episodes_path.read_bytes().split(b"\n")
    run.episodes_path.write_bytes(b"\n".join([*lines[:16], line, *lines[17:]]))
    with pytest.raises(
        StoreError, match=rf"runs/{SMALL}/episodes.jsonl:17: not a JSON row \(.*\); the file is damaged$"
    ):
        run.rows()


def _set_in(*path, value):
    def change(manifest):
        target = manifest
        for key in path[:-1]:
            target = target[key]
        target[path[-1]] = value
        return manifest

    return change


def _drop_command(manifest):
    del manifest["invocations"][0]["command"]
    return manifest


MANIFEST_DAMAGE = {
    "playouts as a string": (_set_in("playouts", value="100"), '"playouts": "100",',
                             "field 'playouts' = '100' is not an integer"),
    "a seed as a string": (_set_in("episode_seeds", 3, value="2000003"), '"2000003",',
                           "field 'episode_seeds.3' = '2000003' is not an integer"),
    "unknown role": (_set_in("role", value="final"), '"role": "final",',
                     "field 'role' = 'final' is not one of 'evaluation', 'validation', 'candidate' or 'superseded'"),
    "margin out of range": (_set_in("world_models", "paper", "caution", "margin", value=9), '"margin": 9',
                            "field 'world_models.paper.caution.margin' = 9 is out of range (should be less than or "
                            "equal to 4)"),
    "a command missing": (_drop_command, '"code_version": ',
                          "field 'invocations.0.command' is missing"),
    "another run's name": (_set_in("name", value="other"), '"name": "other",',
                           "field 'name' = 'other' is not its run's folder name"),
    "an unknown key": (_set_in("seeds", value=[]), '"seeds": []', "field 'seeds' is unknown"),
    "a log key not a seed": (_set_in("log_sha256", "x", value="ab"), '"log_sha256": {',
                             "field 'log_sha256' key 'x' is not a seed"),
}  # fmt: skip


@pytest.mark.parametrize("damage", MANIFEST_DAMAGE, ids=list(MANIFEST_DAMAGE))
def test_a_manifest_that_breaks_the_schema_names_the_file_and_the_line(tmp_path, damage):
    change, marker, message = MANIFEST_DAMAGE[damage]
    run = small_run(tmp_path)
    text = json.dumps(change(json.loads(run.manifest_path.read_text())), indent=1) + "\n"
    run.manifest_path.write_text(text)
    lines = text.splitlines()
    # the line the problem is on (a missing field: the line of the object that lacks it)
    number = next(i for i, line in enumerate(lines, 1) if line.strip().startswith(marker))
    number = number - 1 if damage == "a command missing" else number
    with pytest.raises(StoreError) as caught:
        run.manifest()
    assert f"runs/{SMALL}/manifest.json:{number}: {message}" in str(caught.value)
    assert "\n" not in str(caught.value)
    with pytest.raises(StoreError, match=f"manifest.json:{number}: "):  # every reader of the run refuses it
        run.current()


MANIFEST_CONFLICTS = {
    "a seed the run never listed": (lambda run: edit_row(run, 17, _set("seed", 7)),
                                    "episodes.jsonl:17: field 'seed' = 7 is not one of the run's episode seeds"),
    "other playouts": (lambda run: run.manifest_path.write_text(run.manifest_path.read_text().replace(
                           '"playouts": 100', '"playouts": 200')),
                       "episodes.jsonl:1: field 'playouts' = 100 is not the run's 200 playouts"),
}  # fmt: skip


@pytest.mark.parametrize("damage", MANIFEST_CONFLICTS, ids=list(MANIFEST_CONFLICTS))
def test_a_row_its_manifest_contradicts_is_refused_not_dropped(tmp_path, damage):
    """A row its run cannot have written (its seed is not the manifest's, its playouts are not the run's) is
    named with its line and field by every reader of the counted rows, not left out of the tables."""
    change, message = MANIFEST_CONFLICTS[damage]
    run = small_run(tmp_path)
    change(run)
    with pytest.raises(StoreError) as caught:
        run.current()
    assert f"runs/{SMALL}/{message} (" in str(caught.value) and "\n" not in str(caught.value)


def test_a_row_of_other_provenance_is_kept_and_named_as_not_counted(tmp_path):
    run = small_run(tmp_path)
    edit_row(run, 17, _set("temperature", 0.5))  # a setting its manifest does not ask
    assert len(run.current()) == len(Run(LAB_RESULTS, SMALL).current()) - 1
    assert run.stale() == [(17, "temperature 0.5, the manifest asks None")]


def test_a_torn_manifest_names_its_line(tmp_path):
    run = small_run(tmp_path)
    text = run.manifest_path.read_text()
    run.manifest_path.write_text(text[: text.index('"log_sha256"') + 30])  # cut mid-write by hand
    with pytest.raises(StoreError, match=r"manifest.json:109: not a JSON manifest \(Unterminated string"):
        run.manifest()


def test_a_case_with_two_results_is_refused_naming_both_lines(tmp_path):
    """A second row of a case played with the same provenance that differs from the first would silently change
    the counts (the last row counted); it is an error naming the file and both lines."""
    run = small_run(tmp_path)
    lines = run.episodes_path.read_text().splitlines()
    row = json.loads(lines[4])
    flipped = {**row, "outcome": "death" if row["outcome"] != "death" else "goal"}
    run.episodes_path.write_text("\n".join([*lines, json.dumps(flipped)]) + "\n")
    message = (rf"runs/{SMALL}/episodes.jsonl:201: case technique='samples5' model='paper' agent_speed=1.0 "
               rf"rollout_steps=\d+ seed={row['seed']} has another result with the same provenance at line 5 "
               rf"\(outcome '{row['outcome']}' vs '{flipped['outcome']}'\); keep one of the two lines")  # fmt: skip
    with pytest.raises(StoreError, match=message):
        run.rows()
    with pytest.raises(StoreError, match=message):  # what Table 1 and flows.evaluate read
        run.find(row, {k: row.get(k) for k in ("playouts", "log_sha256", "world_model_sha256", "margin")})


def test_an_identical_repeated_line_is_read_once(tmp_path):
    run = small_run(tmp_path)
    before = run.rows()
    lines = run.episodes_path.read_text().splitlines()
    run.episodes_path.write_text("\n".join([*lines, lines[4]]) + "\n")
    assert run.rows() == before and aggregate(run.current()) == aggregate(Run(LAB_RESULTS, SMALL).current())


def test_a_torn_last_line_is_cut_whatever_it_holds(tmp_path):
    """A last line without its newline is a killed writer's row: reported and left out, not validated."""
    run = small_run(tmp_path)
    before = run.rows()
    lines = run.episodes_path.read_text().splitlines()
    row = {**json.loads(lines[0]), "steps": "abc"}
    run.episodes_path.write_text("\n".join(lines) + "\n" + json.dumps(row))
    with pytest.warns(TornRowWarning, match="line 201 has no newline"):
        assert run.rows() == before
    with pytest.warns(TornRowWarning):
        assert not run.append(before[0])  # cut off; the case is there already
    assert run.episodes_path.read_text() == "\n".join(lines) + "\n"


def test_invalid_rows_and_manifests_are_never_written(tmp_path):
    run = small_run(tmp_path)
    rows, manifest = run.episodes_path.read_bytes(), run.manifest_path.read_bytes()
    good = run.rows()[0]
    with pytest.raises(StoreError, match=rf"runs/{SMALL}/episodes.jsonl: the row to append is invalid: field "
                                         r"'steps' = '27' is not an integer"):  # fmt: skip
        run.append({**good, "seed": 2000100, "steps": "27"})
    with pytest.raises(StoreError, match=r"the manifest to write is invalid: field 'playouts' = 100.0 is not an "):
        run.write_manifest({**run.manifest(), "playouts": 100.0})
    assert (run.episodes_path.read_bytes(), run.manifest_path.read_bytes()) == (rows, manifest)


def test_a_run_folder_that_cannot_be_read_is_refused_by_name(tmp_path, monkeypatch):
    """Its rows would otherwise be left out of every table (a glob skips what it cannot list). The permission is
    denied through `os.access`, as for a user other than the folder's owner (root reads every folder)."""
    import os

    run = small_run(tmp_path)
    denied = os.access
    monkeypatch.setattr(os, "access", lambda path, mode: Path(path) != run.dir and denied(path, mode))
    with pytest.raises(
        StoreError, match=rf"runs/{SMALL}: cannot be read \(permission denied\); what it holds would be left out"
    ):
        check_store(tmp_path)


def test_episodes_without_a_manifest_are_refused(tmp_path):
    run = small_run(tmp_path)
    run.manifest_path.unlink()
    with pytest.raises(StoreError, match=rf"runs/{SMALL}/episodes.jsonl: its run has episodes and no manifest.json"):
        runs(tmp_path)


def test_what_flows_evaluate_reads_names_the_file_and_line(tmp_path):
    """flows.evaluate and Table 1 read the evaluation runs through `load_results`: a damaged row is a StoreError
    (a ValueError: one line from the commands) naming the file and line, never a bare conversion error."""
    shutil.copytree(RESULTS / "runs" / "evaluation", tmp_path / "runs" / "evaluation")
    edit_row(Run(tmp_path), 17, _set("steps", "abc"))
    with pytest.raises(ValueError, match=r"runs/evaluation/episodes.jsonl:17: field 'steps' = 'abc' is not an "):
        aggregate(load_results(tmp_path))


def test_compare_refuses_a_damaged_run_in_one_line(tmp_path, capsys):
    run = small_run(tmp_path)
    edit_row(run, 17, _set("steps", "abc"))
    with pytest.raises(SystemExit) as caught:
        compare_main([str(LAB_RESULTS), SMALL, str(tmp_path), SMALL])
    assert caught.value.code == 2
    assert "episodes.jsonl:17: field 'steps' = 'abc' is not an integer" in capsys.readouterr().err.splitlines()[-1]


@pytest.mark.parametrize("store", [RESULTS, LAB_RESULTS], ids=["product", "lab"])
def test_the_committed_stores_fit_their_schema(store):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no torn rows either
        check_store(store)


# -- the pages ---------------------------------------------------------------------------------------------------
PAGES = ("README.md", "docs/results.md", "datasets/results/table1.json", "datasets/results/table1.md")


@pytest.fixture
def checkout(tmp_path, monkeypatch) -> Path:
    """A copy of what the pages are generated from and into, laid out as in the checkout (the pages name paths
    relative to it): the results store, the training records, docs/results.md and README.md."""
    shutil.copytree(RESULTS, tmp_path / "datasets" / "results")
    for record in (ROOT / "datasets" / "training").glob("*/provenance.json"):
        (tmp_path / "datasets" / "training" / record.parent.name).mkdir(parents=True)
        shutil.copy(record, tmp_path / "datasets" / "training" / record.parent.name)
    (tmp_path / "docs").mkdir()
    shutil.copy(ROOT / "docs" / "results.md", tmp_path / "docs")
    shutil.copy(ROOT / "README.md", tmp_path)
    monkeypatch.setattr(results_module, "ROOT", tmp_path)
    return tmp_path


def _pages(root: Path) -> dict[str, bytes]:
    return {name: (root / name).read_bytes() for name in PAGES}


def _refused(argv: list[str], capsys) -> str:
    with pytest.raises(SystemExit) as caught:
        results_module.main(argv)
    assert caught.value.code == 2
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert line.startswith(f"{COMMAND}: error: ")
    return line


def test_regenerating_from_the_committed_store_writes_the_committed_pages(checkout):
    """`python -m dynplan.evaluation.results` on the committed store writes README.md, docs/results.md and
    table1.{json,md} byte for byte as committed."""
    assert results_module.main([]) == checkout / "docs" / "results.md"
    assert _pages(checkout) == _pages(ROOT)


def test_a_mistyped_results_dir_is_refused_and_not_created(checkout, capsys):
    line = _refused(["--results-dir", str(checkout / "results-typo")], capsys)
    assert f"--results-dir {checkout / 'results-typo'}: no such folder (it is read, never created)" in line
    assert not (checkout / "results-typo").exists() and _pages(checkout) == _pages(ROOT)
    (checkout / "elsewhere").mkdir()
    line = _refused(["--results-dir", str(checkout / "elsewhere")], capsys)
    assert "elsewhere: not a results store (no runs/ folder in it)" in line and _pages(checkout) == _pages(ROOT)


def test_a_store_short_of_the_lab_page_is_refused_unless_asked(tmp_path, capsys):
    """A run gone from the lab's store: docs/runs.md would drop its rows; refused, naming them, and written only
    with --allow-loss."""
    from lab.runs import main as runs_main

    shutil.copytree(LAB_RESULTS, tmp_path / "lab")
    shutil.rmtree(tmp_path / "lab" / "runs" / "validation_margin1")
    page = tmp_path / "runs.md"
    shutil.copy(ROOT / "docs" / "runs.md", page)
    argv = ["--results-dir", str(tmp_path / "lab"), "--reference-dir", str(RESULTS), "--out", str(page)]
    with pytest.raises(SystemExit) as caught:
        runs_main(argv)
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert caught.value.code == 2 and "runs.md would lose 1 entries" in line
    assert "(Validation, candidate and superseded runs / `validation_margin1` / 2× samples5 [default])" in line
    assert line.endswith("; check --results-dir, or pass --allow-loss to write it anyway")
    assert page.read_bytes() == (ROOT / "docs" / "runs.md").read_bytes()
    runs_main([*argv, "--allow-loss"])
    text = page.read_text()
    assert "`validation_margin1`" not in text and "`validation_margin2`" not in text and "`validation`" in text


def test_fewer_episodes_are_a_loss(checkout, capsys):
    """Table 1 counting fewer episodes than the pages show (rows cut from the evaluation) is refused on every
    page that shows them."""
    run = Run(checkout / "datasets" / "results")
    lines = run.episodes_path.read_text().splitlines(keepends=True)
    oracle = [
        i
        for i, line in enumerate(lines)
        if line.startswith('{"technique":"oracle","agent_speed":1.0,"rollout_steps":1,')
    ]
    run.episodes_path.write_text("".join(line for i, line in enumerate(lines) if i not in oracle[:2]))
    line = _refused([], capsys)
    assert "datasets/results/table1.md would lose 1 of its" in line and "docs/results.md would lose 1 of its" in line
    assert "README.md would lose 1 of its" in line
    assert "Table 1 / 2× oracle (ours) (" in line and " → " in line and _pages(checkout) == _pages(ROOT)


def test_a_manifest_with_string_numbers_is_refused_not_dropped(checkout, capsys):
    """Playouts written as "100" would make every row of the run stale and its lines vanish from the page: the
    command refuses, naming the file and line, and writes nothing."""
    run = Run(checkout / "datasets" / "results")
    text = run.manifest_path.read_text()
    run.manifest_path.write_text(text.replace('"playouts": 100,', '"playouts": "100",'))
    number = text[: text.index('"playouts"')].count("\n") + 1
    line = _refused([], capsys)
    assert f"runs/evaluation/manifest.json:{number}: field 'playouts' = '100' is not an integer" in line
    assert _pages(checkout) == _pages(ROOT)


def test_a_loss_names_the_rows_kept_but_not_counted(checkout, capsys):
    """A row with a field its manifest does not ask (a hand edit, another program's key) stops counting: the
    refusal names its file, line and field beside the entry the pages would lose."""
    run = Run(checkout / "datasets" / "results")
    edit_row(run, 5, _set("note", "checked"))
    line = _refused([], capsys)
    assert "would lose 1 of its" in line and _pages(checkout) == _pages(ROOT)
    assert (
        "runs/evaluation/episodes.jsonl: 1 row kept but not counted (played with other provenance than the manifest "
        "asks); the first, line 5: note 'checked', the manifest asks None" in line
    )


def test_lost_entries_name_rows_episodes_and_images():
    page = (ROOT / "docs" / "results.md").read_text()
    entries = page_entries(page)
    assert entries["Table 1 / 2× oracle (ours)"] == 400 and entries["Table 1 / 2× random"] == 100
    runs = page_entries((ROOT / "docs" / "runs.md").read_text())
    assert runs["Validation, candidate and superseded runs / `default_epoch7` / 2× futures5 [default]"] == 370
    assert entries["image figure1_default.png"] == 0
    assert lost_entries(page, page) == [] and lost_entries(page, page + "\n| extra | 1/2/3 |\n") == []
    lines = page.splitlines()
    cut = [line for line in lines if not line.startswith(("| 2× zero (ours)", "![figure1_paper]"))]
    fewer = [line.replace("| 2× oracle (ours) | 100/0/0", "| 2× oracle (ours) | 99/0/0") for line in cut]
    assert lost_entries(page, "\n".join(fewer)) == [
        "Table 1 / 2× oracle (ours) (400 → 399 episodes)", "Table 1 / 2× zero (ours)", "image figure1_paper.png"
    ]  # fmt: skip
