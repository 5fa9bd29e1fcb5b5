"""`python -m dynplan.evaluation.results`: write Table 1 and the results page from the results store.

Writes `datasets/results/table1.{json,md}` (from the evaluation runs), `docs/results.md` (Table 1 beside the paper,
prediction error against the horizon, Figure 1, the causes of the learned agents' deaths and every other world's
section) and the Table 1 block of README.md; the lab's validation and candidate runs are docs/runs.md's
(`python -m lab.runs`). Everything on the page comes from files of the
store; the page is regenerated, never edited (a test compares it with what this command writes).

Nothing a page shows is lost without being asked: a `--results-dir` that does not exist is refused (not created),
and so is a store from which a page would show fewer table rows, episodes or images than it shows now (a mistyped
or partial store would otherwise blank the published tables); `--allow-loss` writes such pages anyway. Every
check runs before the first file is written, and each file is replaced atomically.
"""

from __future__ import annotations

import argparse
import json
import os
import re
from pathlib import Path

from dynplan.cli import CommandParser, InputError, run_command
from dynplan.evaluation.store import shown, stale_report
from dynplan.evaluation.table import aggregate, load_results, render_compact, render_markdown, table_files
from dynplan.files import write_bytes_atomic
from dynplan.paths import PathArgument, PathKind, check_input, check_output
from dynplan.world import DEFAULT_WORLD, world, world_names

ROOT = Path(__file__).resolve().parents[2]
COMMAND = "python -m dynplan.evaluation.results"
PREDICTION = "python -m lab.prediction"
#: How a prediction file's commands start, left out of its title: `PREDICTION`, or the module's name in the
#: committed files (`dynplan.analysis.prediction`).
_PREDICTION_START = re.compile(r"^python -m (?:lab|dynplan\.analysis)\.prediction ")
README_MARKER = "<!-- table1: generated from datasets/results/table1.json -->"
HORIZONS = (1, 3, 5, 10)
#: The causes of a death, as `lab.deaths` counts them.
DEATH_CAUSES = ("off_grid", "foreseen", "spawned", "displaced", "lost")
#: A cell's goals / timeouts / deaths, at its start (not a prediction's "15.1/0.2" nor a death's "1: 0/1/0/0/0").
_GTD_CELL = re.compile(r"(\d+)/(\d+)/(\d+)(?![\d/.])")
_IMAGE = re.compile(r"!\[[^\]]*\]\(([^)\s]+)\)")


class ResultsError(InputError):
    """The pages are not written: the store is not there, or they would lose what they show; the message names the
    path and what is wrong."""


def _pct(x: float) -> str:
    return f"{100 * x:.1f}"


def prediction_section(results: Path, docs: Path) -> list[str]:
    lines = [
        "## Prediction error against the horizon",
        "",
        "Each world model's prediction k steps ahead from 4 observed frames, at 10 decision points of each of 10 "
        "episodes from the seed the title gives: obstacle false negatives / false positives (% of obstacle / "
        "free pixels) and the goal's error (pixels between centres); the title gives the *floor*, the false "
        "negatives no model of the past can avoid (the future repainted with only the obstacles on the road at "
        "the decision). `mid`: the greedy code future decoded to its most likely frame; `N samples`: "
        "N decoded samples merged; `N futures`: N code futures sampled from the prior, merged; occupancy and "
        "margin: the caution (docs/protocol.md §2). A *context bound, N frames* places each obstacle on the "
        "road, and the goal, where their rounded positions over the last N frames most probably put them "
        "(`lab.context_bound`): the best one predicted future from N frames can do. Each file "
        "splits the false negatives by cause: `fn_unforeseeable` (not on the road at the decision), "
        "`fn_displaced` (a predicted obstacle within 2 pixels along its lane), `fn_lost` (the rest). A title "
        f"gives the options of `{PREDICTION}` that wrote the file.",
        "",
    ]
    for path in sorted(results.glob("prediction_*.json")):
        lines += _prediction_table(path, json.loads(path.read_text())["curves"])
        model = path.stem.removeprefix("prediction_")
        plot = results / f"prediction_error_{model}.png"
        if plot.exists():
            lines += [f"![prediction error, {model}]({os.path.relpath(plot, docs)})", ""]
    return lines


def _prediction_title(path: Path, curves: dict[str, dict]) -> str:
    """A file's name, first seed, floor (where measured) and commands (each without `_PREDICTION_START`)."""
    seeds = sorted({c["first_seed"] for c in curves.values() if "first_seed" in c})
    floors = [c["floor_fn_rate"] for c in curves.values() if "floor_fn_rate" in c]
    facts = [f"seeds {', '.join(f'{s:,}' for s in seeds)}…"] if seeds else []
    facts += [f"floor {'/'.join(_pct(floors[0][k - 1]) for k in HORIZONS)}"] if floors else []
    commands = sorted({_PREDICTION_START.sub("", c["command"], count=1) for c in curves.values()})
    return f"`{os.path.relpath(path, ROOT)}` ({'; '.join(facts)}): " + "; ".join(f"`{c}`" for c in commands)


def _prediction_table(path: Path, curves: dict[str, dict]) -> list[str]:
    """One file's curves: a row per prediction, a cell per horizon."""
    header = "| prediction | " + " | ".join(f"k = {k}" for k in HORIZONS) + " |"
    lines = [_prediction_title(path, curves), "", header, "|" + " --- |" * (1 + len(HORIZONS))]
    for name, c in curves.items():
        cells = [
            f"{_pct(c['fn_rate'][k - 1])}/{_pct(c['fp_rate'][k - 1])}, {c['goal_error_px'][k - 1]:.2f}"
            for k in HORIZONS
        ]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return [*lines, ""]


def figure1_section(results: Path, docs: Path) -> list[str]:
    figures = sorted(results.glob("figure1_*.png"))
    if not figures:
        return []
    lines = [
        "## Figure 1: imagined futures beside the truth",
        "",
        "The paper's Figure 1 for each configuration: observed frames, the true future and the predicted one "
        "(written by the `--figure` option of the prediction commands above).",
        "",
    ]
    for figure in figures:
        lines += [f"![{figure.stem}]({os.path.relpath(figure, docs)})", ""]
    return lines


def deaths_section(results: Path) -> list[str]:
    files = sorted(results.glob("deaths_*.json"))
    if not files:
        return []
    ks = sorted({s["k"] for path in files for s in json.loads(path.read_text())["summary"]})
    lines = [
        "## Why the learned agents die",
        "",
        "Each death replayed and classified (`python -m lab.deaths --technique T --model M "
        "--agent-speed S [--run RUN] --out FILE`, written to `datasets/results/deaths_*.json`): *off_grid*; "
        "*foreseen* (the prediction showed the obstacle); *spawned* (it entered the road after the decision, so "
        "no model could foresee it); *displaced* (predicted a few pixels off along its lane); *lost* (not "
        f"predicted at all). Cells: deaths of the episodes (`of N`: other than the line's), then by cause, "
        f"{'/'.join(DEATH_CAUSES)}.",
        "",
        "| file `deaths_…` | agent | episodes | " + " | ".join(f"k = {k}" for k in ks) + " |",
        "|" + " --- |" * (3 + len(ks)),
    ]
    for path in files:
        data = json.loads(path.read_text())
        by_k = {s["k"]: s for s in data["summary"]}
        episodes = max(s["episodes"] for s in by_k.values())
        model = f" [{data['model']}]" if data.get("model") else ""
        agent = f"{data['agent_speed'] * 2:g}× {data['technique']}{model}"
        cells = [_deaths_cell(by_k[k], episodes) if k in by_k else "" for k in ks]
        lines.append(f"| {path.stem.removeprefix('deaths_')} | {agent} | {episodes} | " + " | ".join(cells) + " |")
    return [*lines, ""]


def _deaths_cell(summary: dict, episodes: int) -> str:
    of = f" (of {summary['episodes']})" if summary["episodes"] != episodes else ""
    return f"{summary['deaths']}{of}: " + "/".join(str(summary.get(c, 0)) for c in DEATH_CAUSES)


def results_page(results: Path, docs: Path, rows: list[dict] | None = None) -> str:
    """docs/results.md from the store at `results` (`rows`: Table 1's aggregated rows, if already at hand)."""
    rows = aggregate(load_results(results)) if rows is None else rows
    lines = [
        "# Results",
        "",
        f"Generated by `{COMMAND}` from the results store (`datasets/results/`); do not edit by hand. Each "
        "figure below names the command that measured it; the runs' manifests (`datasets/results/runs/*/"
        "manifest.json`) hold the weights' SHA-256, the caution, the episode seeds, the logs' checksums and "
        "every command line that played them. The validation and candidate runs where settings were chosen are the "
        "lab's: docs/runs.md.",
        "",
        "## Table 1",
        "",
        "100 recorded evaluation episodes (seeds 1,000,000…, level 6), 100 playouts per decision; cells: goals / "
        "timeouts / deaths, and steps (mean ± std over the episodes not died); 2× = 1.0 px/step (T = 203), 1× = "
        "0.5 px/step (T = 407). `[default]` is this project's world-model configuration, `[paper]` the paper's "
        "(docs/protocol.md §2); each `(paper)` line is the paper's Table 1. `futures5` (5 code futures sampled "
        "from the prior) goes beyond the paper. Decision ms: the median over decisions of the search plus the "
        "decision's share of its lockstep batch's prediction, split by the grids each case asked for (docs/"
        "protocol.md §4), played by two single-thread workers on a 2-core CPU.",
        "",
        render_markdown(rows).rstrip("\n"),
        "",
    ]
    lines += prediction_section(results, docs)
    lines += figure1_section(results, docs)
    lines += deaths_section(results)
    lines += worlds_sections(results)
    return "\n".join(lines).rstrip("\n") + "\n"


def worlds_sections(results: Path) -> list[str]:
    """Every other world's section of the page, from its own folder of the store (`WorldParts.results_section`)."""
    lines = []
    for name in world_names():
        section = world(name).load().results_section if name != DEFAULT_WORLD else None
        lines += section(results / name) if section is not None else []
    return lines


def readme_with_table(readme: str, rows: list[dict]) -> str:
    """README.md with the table after its marker replaced by Table 1's compact form (`render_compact`)."""
    if README_MARKER not in readme:
        raise ValueError(f"lacks the marker {README_MARKER!r}")
    head, tail = readme.split(README_MARKER, 1)
    rest = tail.lstrip("\n").split("\n\n", 1)[1] if "\n\n" in tail.lstrip("\n") else ""
    return f"{head}{README_MARKER}\n{render_compact(rows).rstrip()}\n\n{rest}"


def page_entries(text: str) -> dict[str, int]:
    """What a generated page shows, entry by entry, with the episodes each counts: every table row, named by its
    section, its table's title (the name of the file that a line in backquotes leading it names) and its label
    cells (the first and the agent's; ″ repeats the cell above), and every image (by file name: a store read from
    another folder shows the same entries)."""
    entries: dict[str, int] = {}
    section = title = ""
    header: list[str] | None = None
    above: list[str] = []
    for line in text.splitlines():
        if not line.startswith("|"):
            header = None
            if line.startswith("#"):
                section, title = line.lstrip("# "), ""
            elif line.strip():
                title = Path(line.split("`")[1]).name if line.startswith("`") else ""
            entries.update({f"image {Path(target).name}": 0 for target in _IMAGE.findall(line)})
            continue
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if header is None:
            header, above = cells, []
            continue
        if set(line) <= set("|-: "):
            continue
        named = [above[j] if c == "″" and j < len(above) else c for j, c in enumerate(cells)]
        above = named
        labels = [named[j] for j in dict.fromkeys([0, header.index("agent") if "agent" in header else 0])]
        name = " / ".join(part for part in (section, title, *labels) if part)
        while name in entries:
            name += " ″"
        cells_gtd = [_GTD_CELL.match(c) for c in cells[1:]]
        entries[name] = sum(int(m[1]) + int(m[2]) + int(m[3]) for m in cells_gtd if m)
    return entries


def lost_entries(old: str, new: str) -> list[str]:
    """The entries of page `old` (`page_entries`) that page `new` drops or shows with fewer episodes."""
    before, after = page_entries(old), page_entries(new)
    lost = []
    for name, episodes in before.items():
        if name not in after:
            lost.append(name)
        elif after[name] < episodes:
            lost.append(f"{name} ({episodes} → {after[name]} episodes)")
    return lost


def _check_loss(pages: dict[Path, str], results: Path) -> None:
    """A ResultsError naming each page that would lose entries and the first of them."""
    found = []
    for path, text in pages.items():
        if path.suffix != ".md" or not path.is_file():
            continue
        old = path.read_text()
        lost = lost_entries(old, text)
        if lost:
            more = f"; and {len(lost) - 2} more" if len(lost) > 2 else ""
            found.append(
                f"{shown(path)} would lose {len(lost)} of its {len(page_entries(old))} entries "
                f"({'; '.join(lost[:2])}{more})"
            )
    if found:
        stale = "".join(f" | {line}" for line in stale_report(results))  # rows kept but not counted: the likely cause
        raise ResultsError(
            f"the results store {shown(results)} shows less than the pages: "
            + " | ".join(found)
            + stale
            + "; check --results-dir, or pass --allow-loss to write them anyway"
        )


def publish(results: Path, docs: Path, readme: Path | None = None, allow_loss: bool = False) -> list[Path]:
    """Write Table 1 (table1.json, table1.md in `results`), `docs`/results.md and `readme`'s Table 1 from the store
    at `results`; return the paths written. A ResultsError, before anything is written, when the store or the
    README is not there, or a page would lose entries (`lost_entries`) and `allow_loss` is not given."""
    check_input(results, "--results-dir", PathKind.RESULTS_FOLDER)
    if not (results / "runs").is_dir():
        raise ResultsError(f"--results-dir {shown(results)}: not a results store (no runs/ folder in it)")
    check_output(docs, "--docs", "folder", inputs=(results,))
    if readme is not None:
        check_output(readme, "--readme", "file", inputs=(results,))
        if not readme.is_file():
            raise ResultsError(f"--readme {shown(readme)}: no such file")
    rows = aggregate(load_results(results))
    table_json, table_md = table_files(rows)
    pages = {
        results / "table1.json": table_json,
        results / "table1.md": table_md,
        docs / "results.md": results_page(results, docs, rows),
    }
    if readme is not None:
        try:
            pages[readme] = readme_with_table(readme.read_text(), rows)
        except (ValueError, UnicodeDecodeError) as error:
            raise ResultsError(f"--readme {shown(readme)}: {error}") from None
    if not allow_loss:
        _check_loss(pages, results)
    return [write_bytes_atomic(path, text.encode()) for path, text in pages.items()]


def _parser() -> CommandParser:
    parser = CommandParser(prog=COMMAND, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "--results-dir",
        type=PathArgument(PathKind.RESULTS_FOLDER),
        default=str(ROOT / "datasets" / "results"),
        help="the results store (an existing folder)",
    )
    parser.add_argument(
        "--docs", type=PathArgument(PathKind.OUTPUT_FOLDER), default=str(ROOT / "docs"), help="where results.md goes"
    )
    parser.add_argument(
        "--readme", default=str(ROOT / "README.md"), help="the README whose Table 1 to update ('' to leave it)"
    )
    parser.add_argument(
        "--allow-loss",
        action="store_true",
        help="write the pages even where they would show fewer rows, episodes or images than they do now",
    )
    return parser


def main(argv: list[str] | None = None) -> Path:
    """The command: parse `argv`, write the tables and pages (`publish`); a store, README or loss the pages refuse
    is one line on stderr and exit status 2, before anything is written."""
    parser = _parser()
    args = parser.parse_args(argv)
    try:
        written = publish(
            Path(args.results_dir),
            Path(args.docs),
            Path(args.readme) if args.readme else None,
            allow_loss=args.allow_loss,
        )
    except InputError as error:  # StoreError, ResultsError, a table that mixes provenance: all before writing
        parser.error(str(error))
    print("wrote " + ", ".join(map(shown, written)))
    for line in stale_report(args.results_dir):
        print(line)
    return written[2]


if __name__ == "__main__":
    run_command(main, COMMAND)
