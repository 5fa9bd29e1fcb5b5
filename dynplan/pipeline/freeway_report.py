"""Freeway's part of the collect-train-eval report: the run's episodes on the real game beside the oracle and the
public scoreboard, and a GIF of the learned agent's first steps with the lanes it imagined.

The GIF costs a learned agent's decisions; it is redrawn only when the checkpoints change (a manifest of their
SHA-256 sits beside it), so a cached rerun rewrites the report in seconds.
"""

from __future__ import annotations

import json
from itertools import islice
from pathlib import Path

from dynplan.data.store import sha256_file
from dynplan.env.freeway import record_mode
from dynplan.evaluation import freeway
from dynplan.evaluation.freeway_replay import GIF_STEPS, replay_gif
from dynplan.files import write_bytes_atomic
from dynplan.models.checkpoint import digest
from dynplan.pipeline.presets import FreewayEvalPlan
from dynplan.planning.chicken import ChickenSearch

GIF_NAME = "episode.gif"


def draw_gif(out: Path, model_dir: Path, plan: FreewayEvalPlan) -> str:
    """The learned agent's first `GIF_STEPS` steps of the evaluation's first episode (of its first mode), planned
    with the world model in `model_dir` (lanes now with the chicken | true k steps on | imagined | error), into
    `out`; skipped when `out/figures.json` says it was drawn from the same checkpoints. Returns the GIF's name."""
    out.mkdir(parents=True, exist_ok=True)
    mode, horizon = plan.modes[0], plan.horizon
    episode = plan.plans()[0].episode_list()[0]
    identity = {"checkpoints": [sha256_file(model_dir / f"{s}.pt") for s in ("vqvae", "pixelcnn")],
                "mode": mode, "noop_start": episode.noop_start, "k": horizon, "steps": GIF_STEPS}  # fmt: skip
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


def planned_results(results: Path, model_dir: Path, plan: FreewayEvalPlan) -> list[freeway.FreewayResult]:
    """The results of exactly the plan's episodes (each technique's from its run), none other a run may hold."""
    return [
        freeway.read_result(freeway.result_path(results, run_of(t, model_dir), t, mode_plan, plan.horizon, i))
        for mode_plan in plan.plans() for t in plan.techniques for i in range(plan.episodes)
    ]  # fmt: skip


def results_section(rows: list[freeway.FreewayResult], command: str, gif: str | None) -> list[str]:
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
