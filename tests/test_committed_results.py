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
