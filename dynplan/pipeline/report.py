"""The collect-train-eval report: the world's results and pictures (the road's: Table 1 beside the paper,
prediction error against horizon, a Figure-1 image, a GIF of one episode; another world's: its
`PipelineStages.report`), the
stages' wall times, and the config and checkpoint of every stage — as Markdown, and as HTML rendered from it
(markdown-it), with the pictures beside them.

The pictures cost model inference; they are redrawn only when the checkpoints they show change (a manifest of
the checkpoints' SHA-256 sits beside them), so a cached rerun of the pipeline rewrites the report in seconds.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

from dynplan.data.collect import log_path
from dynplan.evaluation.cases import EVAL_SEED_START
from dynplan.evaluation.table import render_markdown
from dynplan.evaluation.techniques import technique as find_technique
from dynplan.files import atomic_path, sha256_file, write_bytes_atomic


@dataclass
class StageRecord:
    """One stage of a run: what it was, how long it took this time, and whether it found its result cached."""

    name: str
    wall_s: float
    detail: str = ""


@dataclass
class CheckpointRecord:
    """A trained (or committed) checkpoint the run used."""

    stage: str
    model: str
    path: str
    config: dict
    epochs: int
    train_hours: float
    last_metrics: dict = field(default_factory=dict)


def checkpoint_record(stage: str, model: str, path: str | os.PathLike) -> CheckpointRecord:
    import torch

    state = torch.load(path, map_location="cpu", weights_only=False)
    last = state["history"][-1] if state.get("history") else {}
    keep = [k for k in last if k.startswith("val_") or k in ("loss", "frames_seen", "patches_seen", "windows_seen")]
    return CheckpointRecord(
        stage,
        model,
        str(path),
        state["config"],
        int(state["epoch"]),
        round(state["elapsed_s"] / 3600, 3),
        {k: last[k] for k in keep},
    )


def draw_figures(
    out: Path,
    models: dict[str, Path],
    eval_logs: Path,
    seed: int,
    rollout_steps: int,
    episodes: int,
    technique: str = "mid",
) -> dict[str, str]:
    """Prediction error against horizon (every configuration), a Figure-1 image and a replay GIF (the first),
    into `out`; skipped when `out/figures.json` says they were drawn from the same checkpoints."""
    from dynplan.evaluation.agent import AgentSpec
    from dynplan.evaluation.prediction import errors_by_horizon, figure1, plot_errors
    from dynplan.evaluation.replay import replay
    from dynplan.models.world_model import load_world_model

    out.mkdir(parents=True, exist_ok=True)
    identity = {m: [sha256_file(folder / f"{s}.pt") for s in ("vqvae", "pixelcnn")] for m, folder in models.items()}
    identity |= {"seed": seed, "k": rollout_steps, "episodes": episodes, "technique": technique}
    manifest = out / "figures.json"
    names = {"errors": "prediction_error.png", "figure1": "figure1.png", "gif": "episode.gif"}
    drawn = manifest.exists() and json.loads(manifest.read_text()).get("identity") == identity
    if drawn and all((out / n).exists() for n in names.values()):
        return names
    chosen = find_technique(technique)
    samples, futures = chosen.samples, chosen.futures
    curves = {}
    for model, folder in models.items():
        curves[f"{model}, {technique}"] = errors_by_horizon(
            load_world_model(folder, model=model, samples=samples, futures=futures), episodes
        )
    with atomic_path(out / names["errors"], keep_suffix=True) as tmp:
        plot_errors(curves, tmp)
    first, folder = next(iter(models.items()))
    with atomic_path(out / names["figure1"], keep_suffix=True) as tmp:
        figure1(load_world_model(folder, model=first, samples=samples, futures=futures), tmp, seed=seed)
    log = log_path(eval_logs, seed)
    agent = AgentSpec(technique=technique, model=first, model_dir=str(folder.parent), rollout_steps=rollout_steps)
    replay(log, agent, agent_speed=1.0, gif=out / names["gif"])  # write_gif is atomic itself
    write_bytes_atomic(manifest, json.dumps({"identity": identity, "curves": curves}, indent=1).encode())
    return names


def table_section(rows: list[dict]) -> list[str]:
    """The road's results: Table 1 of the run."""
    return [
        "Cells are goals / timeouts / deaths and steps (mean ± std over the episodes not died), as in the paper's "
        "Table 1.",
        "",
        "## Table 1",
        "",
        render_markdown(rows) if rows else "(no evaluation results)",
        "",
    ]


def figures_section(figures: dict[str, str] | None) -> list[str]:
    """The road's pictures (none if not drawn)."""
    if not figures:
        return []
    return [
        "## Predictions",
        "",
        f"Prediction error against horizon on held-out episodes (evaluation seeds from {EVAL_SEED_START}):",
        "",
        f"![prediction error]({figures['errors']})",
        "",
        "Figure 1 (per row a step ahead: the true frame, the model's, their error — false negatives red, "
        "false positives blue):",
        "",
        f"![figure 1]({figures['figure1']})",
        "",
        "One evaluation episode planned with the learned model (observed | true at the horizon | predicted | error):",
        "",
        f"![episode]({figures['gif']})",
        "",
    ]


def _purpose(preset: dict) -> list[str]:
    """What the preset is for, and for any but `full` that its few episodes and small models show that every stage
    works, not the paper's figures."""
    lines = [f"Preset `{preset['name']}`: {preset['description']}", ""] if preset.get("description") else []
    if preset["name"] != "full":
        lines += [
            f"**Its few episodes and small models show that every stage works; they are not the paper's figures** "
            f"(`--world {preset['world']} --preset full` plays the protocol; the committed results: docs/results.md).",
            "",
        ]
    return lines


def render_report(
    preset: dict, command: str, results: list[str], stages: list[StageRecord], checkpoints: list[CheckpointRecord]
) -> str:
    """The report's Markdown: `results` (the world's results and pictures, Markdown lines), then the stages,
    checkpoints and preset."""
    lines = [
        f"# dynplan collect-train-eval report: {preset['world']} preset `{preset['name']}`",
        "",
        f"Regenerate with `{command}`. Learned rows use the world models trained (or, with `pretrained`, "
        "copied from the committed weights) by this run.",
        "",
        *_purpose(preset),
        *results,
    ]
    lines += ["## Stages", "", "| stage | wall time (s) | detail |", "| --- | ---: | --- |"]
    lines += [f"| {s.name} | {s.wall_s:.1f} | {s.detail} |" for s in stages]
    lines += ["", f"Total: {sum(s.wall_s for s in stages):.1f} s.", "", "## Checkpoints", ""]
    for c in checkpoints:
        metrics = ", ".join(f"{k} {v:.4g}" for k, v in c.last_metrics.items())
        lines += [
            f"### {c.stage} `{c.model}`",
            "",
            f"`{c.path}` — {c.epochs} epochs, {c.train_hours} h of training. Last epoch: {metrics}.",
            "",
            "```json",
            json.dumps(c.config),
            "```",
            "",
        ]
    lines += ["## Preset", "", "```json", json.dumps(preset, indent=1), "```", ""]
    return "\n".join(lines)


def write_report(out: Path, markdown: str) -> tuple[Path, Path]:
    """report.md and report.html (same content) into `out`, atomically."""
    from markdown_it import MarkdownIt

    body = MarkdownIt("commonmark").enable("table").render(markdown)
    html = (
        "<!doctype html><html><head><meta charset='utf-8'><title>dynplan report</title><style>"
        "body{font-family:sans-serif;max-width:70em;margin:2em auto}table{border-collapse:collapse}"
        "td,th{border:1px solid #ccc;padding:.2em .5em}img{image-rendering:pixelated;max-width:100%}"
        f"</style></head><body>{body}</body></html>"
    )
    md = write_bytes_atomic(out / "report.md", markdown.encode())
    return md, write_bytes_atomic(out / "report.html", html.encode())
