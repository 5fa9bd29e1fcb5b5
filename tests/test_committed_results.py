"""The committed Table 1 rows of learned world models are what their committed per-episode results add up to.

Learned rows took hours of evaluation and are committed per episode; a table regenerated from files that were
never committed (a fresh clone lacks them) would claim episodes nobody can reproduce."""

import json
from pathlib import Path

import pytest

from dynplan.evaluation.table import aggregate, load_results

RESULTS = Path(__file__).resolve().parents[1] / "datasets" / "results"
FOLDERS = sorted(p.parent for p in RESULTS.glob("**/table1.json") if (p.parent / "episodes").is_dir())


def _learned(rows: list[dict]) -> dict[tuple, tuple]:
    return {(r["technique"], r["model"], r["agent_speed"], r["rollout_steps"]): (r["episodes"], r["G"], r["T"], r["D"])
            for r in rows if r.get("model")}  # fmt: skip


@pytest.mark.parametrize("folder", FOLDERS, ids=lambda p: str(p.relative_to(RESULTS.parent)))
def test_committed_learned_rows_match_their_episodes(folder):
    table = _learned(json.loads((folder / "table1.json").read_text()))
    assert table, f"{folder}/table1.json has no learned rows"
    assert _learned(aggregate(load_results(folder))) == table


README = RESULTS.parents[1] / "README.md"
TABLE_MARKER = "<!-- table1: copied from datasets/results/table1.md -->"


def _table_lines(text: str) -> list[str]:
    """The Markdown table rows of `text` (lines starting with '|'), in order."""
    return [line for line in text.splitlines() if line.startswith("|")]


def test_readme_table1_is_the_committed_table():
    """The README's Table 1 is a copy of datasets/results/table1.md: it must not drift from the committed results
    (regenerate with `python -m flows.evaluate`, then paste the table's rows after the marker)."""
    readme = README.read_text()
    assert TABLE_MARKER in readme, f"README.md lost its marker {TABLE_MARKER!r}"
    copied = readme.split(TABLE_MARKER, 1)[1].lstrip("\n").split("\n\n", 1)[0]
    committed = _table_lines((RESULTS / "table1.md").read_text())
    assert len(committed) > 2, "datasets/results/table1.md has no rows"
    assert _table_lines(copied) == committed
