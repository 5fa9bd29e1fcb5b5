"""Freeway's part of the collect-train-eval report: the run's episodes on the real game beside the oracle and the
public scoreboard, and a GIF of the learned agent's first steps with the lanes it imagined.

The GIF costs a learned agent's decisions; it is redrawn only when the checkpoints change (a manifest of their
SHA-256 sits beside it), so a cached rerun rewrites the report in seconds.
"""

from __future__ import annotations

import json
from itertools import islice
from pathlib import Path

from dynplan.config import digest
from dynplan.evaluation.store import StoreError, shown
from dynplan.files import sha256_file, write_bytes_atomic
from dynplan.worlds.freeway import evaluation as freeway
from dynplan.worlds.freeway.commands import FreewayEvaluation
from dynplan.worlds.freeway.game import record_mode
from dynplan.worlds.freeway.presets import FreewayEvalPlan
from dynplan.worlds.freeway.replay import GIF_STEPS, replay_gif
from dynplan.worlds.freeway.results import RUNS
from dynplan.worlds.freeway.search import ChickenSearch

GIF_NAME = "episode.gif"


def draw_gif(out: Path, model_dir: Path, plan: FreewayEvalPlan) -> str:
    """The learned agent's first `GIF_STEPS` steps of the evaluation's first episode (of its first mode), planned
    with the world model in `model_dir` (lanes now with the chicken | true k steps on | imagined | error), into
    `out`; skipped when `out/figures.json` says it was drawn from the same checkpoints. Returns the GIF's name."""
    out.mkdir(parents=True, exist_ok=True)
    mode, horizon = plan.modes[0], plan.horizon
    episode = plan.plans()[0].episode_list()[0]
    identity = {
        "checkpoints": [sha256_file(model_dir / f"{s}.pt") for s in ("vqvae", "pixelcnn")],
        "mode": mode,
        "noop_start": episode.noop_start,
        "k": horizon,
        "steps": GIF_STEPS,
    }
    manifest = out / "figures.json"
    if manifest.exists() and json.loads(manifest.read_text()).get("identity") == identity and (out / GIF_NAME).exists():
        return GIF_NAME
    model = freeway.world_model_for("learned", model_dir)
    turns = list(islice(freeway.play_turns("learned", episode, ChickenSearch(horizon=horizon), model=model), GIF_STEPS))
    replay_gif(out / GIF_NAME, turns, record_mode(mode).frames, episode.noop_start)
    write_bytes_atomic(manifest, json.dumps({"identity": identity}, indent=1).encode())
    return GIF_NAME


#: The run of the techniques that do not read the world model: their episodes hold whatever the weights.
REFERENCE_RUN = "reference"


def weights_run(model_dir: Path) -> str:
    """The run of the learned technique's episodes: named by the checkpoints' SHA-256, so new weights play anew and
    the same weights reuse what they played."""
    return "weights-" + digest(*(sha256_file(model_dir / f"{s}.pt") for s in ("vqvae", "pixelcnn")))[:12]


def run_of(technique: str, model_dir: Path) -> str:
    """The run `technique`'s episodes go to."""
    return weights_run(model_dir) if technique == "learned" else REFERENCE_RUN


def planned_results(results: Path, model_dir: Path, plan: FreewayEvalPlan) -> list[dict]:
    """The rows of exactly the plan's episodes (each technique's from its run), none other a run may hold; a
    StoreError naming the run when one is missing."""
    rows = []
    for technique in plan.techniques:
        run = run_of(technique, model_dir)
        held = {RUNS.case_key(row): row for row in freeway.read_run(results, run)}
        for mode_plan in plan.plans():
            for i in range(plan.episodes):
                case = freeway.case_of(technique, mode_plan, i, plan.horizon)
                if RUNS.case_key(case) not in held:
                    raise StoreError(f"{shown(results / 'runs' / run)}: holds no episode {case}")
                rows.append(held[RUNS.case_key(case)])
    return rows


def results_section(rows: list[dict], command: str, gif: str | None) -> list[str]:
    """The run's Freeway table (a row per technique, a column per mode) and, when drawn, the learned agent's GIF."""
    played = "the episodes played at once by the run's task runner"
    lines = freeway.results_table(rows, command, played)
    if gif:
        lines += [
            "The learned agent's first steps (lanes now with the chicken | true lanes k steps on | the lanes "
            "it imagined | error: false negatives red, false positives blue):",
            "",
            f"![episode]({gif})",
            "",
        ]
    return lines


class Stages:
    """Freeway's part of `collect-train-eval`: the learned technique's episodes into a run named by the checkpoints,
    the others' into the reference run (they do not read the weights); the report's table of exactly the plan's
    episodes and the learned agent's GIF."""

    def evaluations(self, preset, work: Path) -> list[FreewayEvaluation]:
        e, models = preset.evaluation, work / "models" / preset.models[0]
        by_run: dict[str, list[str]] = {}
        for technique in e.techniques:
            by_run.setdefault(run_of(technique, models), []).append(technique)
        return [
            FreewayEvaluation(
                techniques=techniques,
                modes=e.modes,
                episodes=e.episodes,
                seed=e.seed,
                horizon=e.horizon,
                results=str(work / "results"),
                run=run,
                model_dir=str(models),
            )
            for run, techniques in by_run.items()
        ]

    def report(self, preset, work: Path, out: Path, command: str) -> list[str]:
        models = work / "models" / preset.models[0]
        gif = draw_gif(out, models, preset.evaluation) if preset.learned_techniques else None
        rows = planned_results(work / "results", models, preset.evaluation)
        return results_section(rows, command, gif)
