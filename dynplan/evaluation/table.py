"""Aggregate per-episode results into the paper's Table 1: G / T / D and S (mean ± std of steps over the
episodes not died), with decision times, side by side with the paper's numbers."""

from __future__ import annotations

import json
import os
from collections import defaultdict
from pathlib import Path

import numpy as np

from dynplan.evaluation.paper import PAPER_RANDOM_GOALS, PAPER_TABLE1
from dynplan.evaluation.store import StoreError, evaluation_rows
from dynplan.evaluation.techniques import TECHNIQUES
from dynplan.files import write_bytes_atomic
from dynplan.models.caution import Caution

#: What every episode of one table row must share: a row never mixes results played differently.
SHARED = ("playouts", "world_model_sha256", *Caution.model_fields)


def load_results(results_dir: str | os.PathLike) -> list[dict]:
    """The rows Table 1 counts in the store at `results_dir`: the current rows of its evaluation runs."""
    return evaluation_rows(results_dir)


def _check_provenance(label: str, episodes: list[dict]) -> None:
    """Refuse a row whose episodes differ in what they were played with, or that holds an episode twice."""
    for field in SHARED:
        values = {json.dumps(e.get(field)) for e in episodes}
        if len(values) > 1:
            raise StoreError(
                f"the results of {label} mix {field} values {sorted(values)}: a row of Table 1 counts "
                f"episodes played the same way only"
            )
    seeds = [e.get("seed") for e in episodes]
    twice = sorted({s for s in seeds if s is not None and seeds.count(s) > 1})
    if twice:
        raise StoreError(f"the results of {label} hold seed(s) {twice} more than once")


def _sort_key(row: dict) -> tuple:
    technique = row["technique"]
    order = list(TECHNIQUES)  # Table 1's order is the registry's
    rank = order.index(technique) if technique in order else len(order)
    return (-row["agent_speed"], rank, technique, row.get("model") or "", row["rollout_steps"] or 0)


def aggregate(results: list[dict]) -> list[dict]:
    """One row per (technique, agent speed, rollout steps)."""
    groups: dict[tuple, list[dict]] = defaultdict(list)
    for r in results:
        groups[(r["technique"], r.get("model"), r["agent_speed"], r["rollout_steps"])].append(r)
    rows = []
    for (technique, model, speed, k), episodes in groups.items():
        _check_provenance(f"{technique}" + (f" [{model}]" if model else "") + f" at speed {speed}, k={k}", episodes)
        playouts = {e.get("playouts") for e in episodes}
        outcomes = [e["outcome"] for e in episodes]
        survived = np.array([e["steps"] for e in episodes if e["outcome"] != "death"], dtype=np.float64)
        times = np.concatenate([np.asarray(e["decision_ms"], dtype=np.float64) for e in episodes])
        rows.append(
            {
                "technique": technique,
                "model": model,
                "agent_speed": speed,
                "rollout_steps": k,
                "episodes": len(episodes),
                "playouts": playouts.pop(),
                "G": outcomes.count("goal"),
                "T": outcomes.count("timeout"),
                "D": outcomes.count("death"),
                "S_mean": round(float(survived.mean()), 1) if len(survived) else None,
                "S_std": round(float(survived.std()), 1) if len(survived) else None,
                "decision_ms_median": round(float(np.median(times)), 4) if len(times) else None,
                "decision_ms_mean": round(float(times.mean()), 4) if len(times) else None,
                "wall_s": round(sum(e["wall_s"] for e in episodes), 1),
            }
        )
    return sorted(rows, key=_sort_key)


def _cell(g, t, d, s_mean, s_std) -> str:
    s = "–" if s_mean is None else f"{s_mean:.0f} ± {s_std:.0f}"
    return f"{g}/{t}/{d}, {s}"


def _ms(value: float | None) -> str:
    """A decision time for the table: three significant digits, whole milliseconds from 100 on."""
    if value is None:
        return ""
    return f"{value:.3g}" if value < 100 else f"{value:.0f}"


def render_markdown(rows: list[dict]) -> str:
    """The table in the paper's layout: one line per technique and speed, a cell per rollout length."""
    ks = sorted({r["rollout_steps"] for r in rows if r["rollout_steps"] is not None})
    by_key = {(r["technique"], r.get("model"), r["agent_speed"], r["rollout_steps"]): r for r in rows}
    full = max((r["episodes"] for r in rows), default=0)  # a case still being played has fewer: say so
    header = "| technique | " + " | ".join(f"k = {k}: G/T/D, S" for k in ks) + " | decision ms (median) |"
    lines = [header, "|" + " --- |" * (len(ks) + 2)]
    seen = []
    for r in rows:
        key = (r["technique"], r.get("model"), r["agent_speed"])
        if key in seen:
            continue
        seen.append(key)
        technique, model, speed = key
        label = f"{speed * 2:g}× {technique}" + (f" [{model}]" if model else "")
        if technique == "random":
            r0 = by_key[(technique, None, speed, None)]
            paper = PAPER_RANDOM_GOALS.get(speed)
            note = f" (paper: {paper} goals)" if paper is not None else ""
            cell = _cell(r0["G"], r0["T"], r0["D"], r0["S_mean"], r0["S_std"]) + note
            lines.append(
                f"| {label} | " + " | ".join([cell] + ["″"] * (len(ks) - 1)) + f" | {_ms(r0['decision_ms_median'])} |"
            )
            continue
        cells, paper_cells, times = [], [], []
        for k in ks:
            row = by_key.get((technique, model, speed, k))
            partial = f" (of {row['episodes']} so far)" if row and row["episodes"] < full else ""
            cells.append(_cell(row["G"], row["T"], row["D"], row["S_mean"], row["S_std"]) + partial if row else "")
            times.append(_ms(row["decision_ms_median"]) if row else "")
            paper = PAPER_TABLE1.get((technique, speed, k))
            paper_cells.append(_cell(*paper) if paper else "")
        lines.append(f"| {label} (ours) | " + " | ".join(cells) + " | " + " / ".join(t for t in times if t) + " |")
        if any(paper_cells):
            lines.append(f"| {label} (paper) | " + " | ".join(paper_cells) + " | |")
    return "\n".join(lines) + "\n"


def render_compact(rows: list[dict]) -> str:
    """The README's summary of `render_markdown`'s table: the oracle and the techniques the paper reports, goals /
    timeouts / deaths per k — ours, the paper's in brackets — and the random agent's goals against the paper's."""
    ks = sorted({r["rollout_steps"] for r in rows if r["rollout_steps"] is not None})
    reported = {(technique, speed) for technique, speed, _ in PAPER_TABLE1}
    by_key = {(r["technique"], r.get("model"), r["agent_speed"], r["rollout_steps"]): r for r in rows}
    lines = ["| agent | " + " | ".join(f"k = {k}" for k in ks) + " |", "|" + " --- |" * (len(ks) + 1)]
    for technique, model, speed in dict.fromkeys((r["technique"], r.get("model"), r["agent_speed"]) for r in rows):
        label = f"{speed * 2:g}× {technique}" + (f" [{model}]" if model else "")
        if technique == "random":
            r0 = by_key[(technique, None, speed, None)]
            goals = PAPER_RANDOM_GOALS.get(speed)
            paper = "" if goals is None else f" ({goals} goal{'' if goals == 1 else 's'})"
            cells = [f"{r0['G']}/{r0['T']}/{r0['D']}{paper}"] + ["″"] * (len(ks) - 1)
        elif (technique, speed) in reported:
            cells = []
            for k in ks:
                row, paper = by_key.get((technique, model, speed, k)), PAPER_TABLE1.get((technique, speed, k))
                ours = f"{row['G']}/{row['T']}/{row['D']}" if row else "–"
                cells.append(ours + (f" ({paper[0]}/{paper[1]}/{paper[2]})" if paper else ""))
        else:
            continue
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def table_files(rows: list[dict]) -> tuple[str, str]:
    """The text of table1.json and of table1.md for `rows` (a pure function: the same rows, the same text)."""
    text = (
        "# Table 1: MCTS agents over the same recorded episodes\n\n"
        "Built from the evaluation runs of the results store (`runs/*/manifest.json` with role `evaluation`; "
        "each manifest lists the commands that played it) by `python -m flows.evaluate` or "
        "`python -m dynplan.evaluation.results`. A row plays with `python -m flows.evaluate --techniques TECHNIQUE "
        "[--models MODEL]` (100 episodes, 100 playouts, both speeds, k = 1, 3, 5, 10 by default). Cells: goals / "
        "timeouts / deaths, and steps (mean ± std over the episodes not died). Speeds: 2× = 1.0 px/step (T = 203), "
        "1× = 0.5 px/step (T = 407).\n\n" + render_markdown(rows)
    )
    return json.dumps(rows, indent=1) + "\n", text


def write_table(rows: list[dict], results_dir: str | os.PathLike) -> tuple[Path, Path]:
    """Write table1.json and table1.md into `results_dir`, each atomically (`table_files`)."""
    results_dir = Path(results_dir)
    json_text, md_text = table_files(rows)
    json_path = write_bytes_atomic(results_dir / "table1.json", json_text.encode())
    md_path = write_bytes_atomic(results_dir / "table1.md", md_text.encode())
    return json_path, md_path
