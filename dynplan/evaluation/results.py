"""`python -m dynplan.evaluation.results`: write Table 1 and the results page from the results store.

Writes `datasets/results/table1.{json,md}` (from the evaluation runs), `docs/results.md` (Table 1 beside the paper,
prediction error against the horizon, Figure 1, the causes of the learned agents' deaths, and every validation,
candidate and superseded run) and the Table 1 block of README.md. Everything on the page comes from files of the
store; the page is regenerated, never edited (a test compares it with what this command writes).
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

from dynplan.evaluation.store import ROLES, runs
from dynplan.evaluation.table import aggregate, load_results, render_markdown, write_table
from dynplan.files import write_bytes_atomic

ROOT = Path(__file__).resolve().parents[2]
COMMAND = "python -m dynplan.evaluation.results"
README_MARKER = "<!-- table1: generated from datasets/results/table1.md -->"
#: What each role's section says.
ROLE_TITLES = {
    "validation": "Validation runs: where each setting was chosen (seeds 2,000,000…)",
    "candidate": "Candidate runs: weights or settings replayed on the evaluation episodes, not adopted",
    "superseded": "Superseded evaluations: the rows of weights or settings committed before the current ones",
}
HORIZONS = (1, 3, 5, 10)


def _pct(x: float) -> str:
    return f"{100 * x:.1f}"


def _caution(entry: dict) -> str:
    return ", ".join(f"{k} {v:g}" for k, v in sorted(entry.get("caution", {}).items())) or "none"


def prediction_section(results: Path, docs: Path) -> list[str]:
    lines = ["## Prediction error against the horizon", "",
             "Obstacle false negatives (% of true obstacle pixels), false positives (% of free pixels) and the goal's "
             "error (pixels between centres) of each world model's prediction k steps ahead, from 4 observed frames, "
             "over 10 decision points of each of the first 10 evaluation episodes (seeds 1,000,000…). `mid` is the "
             "greedy code future decoded to its most likely frame; `N samples` merges N decoded samples; `N futures` "
             "merges N code futures sampled from the prior; occupancy and margin are the default configuration's "
             "caution (docs/protocol.md §2). A *context bound, N frames* places each obstacle on the road at the "
             "decision, and the goal, where their rounded positions over the last N frames most probably put them "
             "(`dynplan.analysis.context_bound`): the best a single predicted future from N frames can do.",
             ""]  # fmt: skip
    for path in sorted(results.glob("prediction_*.json")):
        curves = json.loads(path.read_text())["curves"]
        header = " | ".join(f"k = {k}: FN / FP, goal" for k in HORIZONS)
        lines += [f"`{os.path.relpath(path, ROOT)}`:", "", f"| prediction | {header} |",
                  "|" + " --- |" * (1 + len(HORIZONS))]  # fmt: skip
        for name, c in curves.items():
            cells = [f"{_pct(c['fn_rate'][k - 1])} / {_pct(c['fp_rate'][k - 1])}, {c['goal_error_px'][k - 1]:.2f}"
                     for k in HORIZONS]  # fmt: skip
            lines.append(f"| {name} | " + " | ".join(cells) + " |")
        lines += ["", "Commands: " + "; ".join(sorted({f"`{c['command']}`" for c in curves.values()})), ""]
        lines += _causes_table(curves)
        model = path.stem.removeprefix("prediction_")
        plot = results / f"prediction_error_{model}.png"
        if plot.exists():
            lines += [f"![prediction error, {model}]({os.path.relpath(plot, docs)})", ""]
    return lines


def _causes_table(curves: dict[str, dict]) -> list[str]:
    """The false negatives of each curve by cause against the floor (`analysis.prediction.miss_causes`)."""
    measured = {name: c for name, c in curves.items() if "floor_fn_rate" in c}
    if not measured:
        return []
    floor = next(iter(measured.values()))["floor_fn_rate"]
    lines = ["False negatives by cause (% of true obstacle pixels): *unforeseeable* (the obstacle had not entered the "
             "road at the decision), *displaced* (a predicted obstacle within 2 pixels along its lane), *lost* (the "
             "rest); the false-negative rate is their sum, shown as a multiple of the floor — the share no model of "
             "the past can foresee (the future repainted with only the obstacles on the road at the decision).", "",
             "| prediction | " + " | ".join(f"k = {k}: unforeseeable / displaced / lost (× floor)" for k in HORIZONS)
             + " |", "|" + " --- |" * (1 + len(HORIZONS)),
             "| floor | " + " | ".join(_pct(floor[k - 1]) for k in HORIZONS) + " |"]  # fmt: skip
    for name, c in measured.items():
        cells = [f"{_pct(c['fn_unforeseeable'][k - 1])} / {_pct(c['fn_displaced'][k - 1])} / "
                 f"{_pct(c['fn_lost'][k - 1])} ({c['fn_rate'][k - 1] / max(floor[k - 1], 1e-9):.1f}×)"
                 for k in HORIZONS]  # fmt: skip
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return [*lines, ""]


def figure1_section(results: Path, docs: Path) -> list[str]:
    figures = sorted(results.glob("figure1_*.png"))
    if not figures:
        return []
    lines = ["## Figure 1: imagined futures beside the truth", "",
             "The paper's Figure 1 for each configuration: observed frames, the true future and the predicted one "
             "(written by the `--figure` option of the prediction commands above).", ""]  # fmt: skip
    for figure in figures:
        lines += [f"![{figure.stem}]({os.path.relpath(figure, docs)})", ""]
    return lines


def deaths_section(results: Path) -> list[str]:
    files = sorted(results.glob("deaths_*.json"))
    if not files:
        return []
    lines = ["## Why the learned agents die", "",
             "Each death replayed and classified (`python -m dynplan.analysis.deaths --technique T --model M "
             "--agent-speed S [--run RUN] --out FILE`): *off_grid*; *foreseen* (the prediction showed the obstacle); "
             "*spawned* (it entered the road after the decision, so no model could foresee it); *displaced* (predicted "
             "a few pixels off along its lane); *lost* (not predicted at all).", ""]  # fmt: skip
    causes = ("off_grid", "foreseen", "spawned", "displaced", "lost")
    lines += ["| file | agent | k | episodes | deaths | " + " | ".join(causes) + " |",
              "|" + " --- |" * (5 + len(causes))]  # fmt: skip
    for path in files:
        data = json.loads(path.read_text())
        model = f" [{data['model']}]" if data.get("model") else ""
        agent = f"{data['agent_speed'] * 2:g}× {data['technique']}{model}"
        for s in data["summary"]:
            lines.append(f"| `{path.name}` | {agent} | {s['k']} | {s['episodes']} | {s['deaths']} | "
                         + " | ".join(str(s.get(c, 0)) for c in causes) + " |")  # fmt: skip
    return [*lines, ""]


def _compact(rows: list[dict]) -> list[str]:
    lines = ["| agent | k | episodes | goals / timeouts / deaths |", "| --- | --- | --- | --- |"]
    for r in rows:
        agent = f"{r['agent_speed'] * 2:g}× {r['technique']}" + (f" [{r['model']}]" if r.get("model") else "")
        k = "–" if r["rollout_steps"] is None else r["rollout_steps"]
        lines.append(f"| {agent} | {k} | {r['episodes']} | {r['G']} / {r['T']} / {r['D']} |")
    return lines


def runs_section(results: Path, role: str) -> list[str]:
    chosen = runs(results, role)
    if not chosen:
        return []
    lines = [f"## {ROLE_TITLES[role]}", "",
             "Commands in today's form (`--run NAME`; `MODEL_DIR` holds the run's weights as "
             "`<model>/{vqvae,pixelcnn}.pt`); each manifest keeps the command line exactly as it was run.",
             ""]  # fmt: skip
    for run in chosen:
        manifest = run.manifest()
        models = manifest["world_models"]
        lines += [f"### `{run.name}`", ""]
        for model, entry in sorted(models.items()):
            weights = ", ".join(f"`{w}`" for w in entry.get("weights", [])) or "unnamed weights"
            short = " + ".join(f"{h[:12]}…" for h in entry["weights_sha256"].split("+"))
            lines.append(f"- {model}: {weights} (SHA-256 `{short}`), caution: "
                         f"{_caution(entry)}")  # fmt: skip
        commands = [i.get("equivalent", i["command"]) for i in manifest["invocations"]]
        lines += [f"- {manifest['playouts']} playouts; commands: " + "; ".join(f"`{c}`" for c in commands), ""]
        lines += [*_compact(aggregate(run.current())), ""]
    return lines


def results_page(results: Path, docs: Path) -> str:
    rows = aggregate(load_results(results))
    lines = ["# Results", "",
             f"Generated by `{COMMAND}` from the results store (`datasets/results/`); do not edit by hand. Each "
             "figure below names the command that measured it; the runs' manifests (`datasets/results/runs/*/"
             "manifest.json`) hold the weights' SHA-256, the caution, the episode seeds, the logs' checksums and "
             "every command line that played them.", "",
             "## Table 1", "",
             "100 recorded evaluation episodes (seeds 1,000,000…, level 6), 100 playouts per decision; cells: goals / "
             "timeouts / deaths, and steps (mean ± std over the episodes not died); 2× = 1.0 px/step (T = 203), 1× = "
             "0.5 px/step (T = 407). `[default]` is this project's world-model configuration, `[paper]` the paper's "
             "(docs/protocol.md §2); each `(paper)` line is the paper's Table 1. `futures5` (5 code futures sampled "
             "from the prior) goes beyond the paper. Decision ms: the median over decisions of the search plus the "
             "decision's share of its lockstep batch's prediction, split by the grids each case asked for (docs/"
             "protocol.md §4), played by two single-thread workers on a 2-core CPU.", "",
             render_markdown(rows).rstrip("\n"), ""]  # fmt: skip
    lines += prediction_section(results, docs)
    lines += figure1_section(results, docs)
    lines += deaths_section(results)
    for role in ROLES:
        if role in ROLE_TITLES:
            lines += runs_section(results, role)
    return "\n".join(lines).rstrip("\n") + "\n"


def readme_with_table(readme: str, table_md: str) -> str:
    """README.md with the table rows after its marker replaced by those of `table_md`."""
    if README_MARKER not in readme:
        raise ValueError(f"README.md lacks the marker {README_MARKER!r}")
    head, tail = readme.split(README_MARKER, 1)
    rest = tail.lstrip("\n").split("\n\n", 1)[1] if "\n\n" in tail.lstrip("\n") else ""
    table = "\n".join(line for line in table_md.splitlines() if line.startswith("|"))
    return f"{head}{README_MARKER}\n{table}\n\n{rest}"


def main(argv: list[str] | None = None) -> Path:
    parser = argparse.ArgumentParser(prog=COMMAND, description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    parser.add_argument("--results-dir", default=str(ROOT / "datasets" / "results"), help="the results store")
    parser.add_argument("--docs", default=str(ROOT / "docs"), help="where results.md goes")
    parser.add_argument("--readme", default=str(ROOT / "README.md"), help="the README whose Table 1 to update "
                        "('' to leave it)")  # fmt: skip
    args = parser.parse_args(argv)
    results, docs = Path(args.results_dir), Path(args.docs)
    _, table_md = write_table(aggregate(load_results(results)), results)
    page = write_bytes_atomic(docs / "results.md", results_page(results, docs).encode())
    if args.readme:
        readme = Path(args.readme)
        write_bytes_atomic(readme, readme_with_table(readme.read_text(), table_md.read_text()).encode())
    print(f"wrote {table_md.parent / 'table1.json'}, {table_md}, {page}" + (f", {args.readme}" if args.readme else ""))
    return page


if __name__ == "__main__":
    main()
