"""MiniGrid's part of the collect-train-eval report: the run's rooms by technique, and the learned agent's first
room as a GIF (the room now with the agent | the true room k steps on | a room the world model imagined there |
its chance of a ball in each cell) and a replay log.

The GIF and the log cost a learned agent's decisions; they are drawn again only when the checkpoints change (a
manifest of their SHA-256 sits beside them), so a cached rerun rewrites the report in seconds.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from dynplan.evaluation.store import Run, StoreError, shown
from dynplan.files import sha256_file, write_bytes_atomic
from dynplan.models.weights import world_model_paths
from dynplan.render import write_gif
from dynplan.worlds.minigrid.commands import MiniGridEvaluation
from dynplan.worlds.minigrid.evaluation import summarise
from dynplan.worlds.minigrid.grid import MiniGridConfig, record_world
from dynplan.worlds.minigrid.models import NAME
from dynplan.worlds.minigrid.play import MiniGridPlay, play_out
from dynplan.worlds.minigrid.presets import MiniGridEvalPlan
from dynplan.worlds.minigrid.results import LEARNED_SAMPLES, RUNS

GIF_NAME, LOG_NAME = "episode.gif", "episode.mcap"
#: Steps the GIF shows at most (an episode to the goal takes about 30).
GIF_STEPS = 60


def draw_episode(out: Path, model_dir: Path, plan: MiniGridEvalPlan) -> str:
    """The first learned technique's episode in the evaluation's first room, planned with the world model in
    `model_dir`, as a GIF (its first `GIF_STEPS` steps) and a replay log in `out`; skipped when `out/figures.json`
    says they were drawn from the same checkpoints. Returns the GIF's name."""
    out.mkdir(parents=True, exist_ok=True)
    technique = plan.learned_techniques[0]
    identity = {
        "checkpoints": [sha256_file(p) for p in world_model_paths(NAME, model_dir)],
        "technique": technique,
        "seed": plan.first_seed,
        "steps": GIF_STEPS,
    }
    manifest = out / "figures.json"
    drawn = manifest.exists() and json.loads(manifest.read_text()).get("identity") == identity
    if drawn and (out / GIF_NAME).exists() and (out / LOG_NAME).exists():
        return GIF_NAME
    from dynplan.worlds.minigrid.imagine import MiniGridModel  # torch: imported by the work, not by `--help`

    room = record_world(MiniGridConfig(), plan.first_seed)
    state = MiniGridPlay(room, technique, model=MiniGridModel(model_dir))
    write_gif(out / GIF_NAME, np.stack(play_out(state, GIF_STEPS)), fps=4, scale=8)
    state.record(out / LOG_NAME)
    write_bytes_atomic(manifest, json.dumps({"identity": identity}, indent=1).encode())
    return GIF_NAME


def planned_rows(request: MiniGridEvaluation) -> list[dict]:
    """The rows of exactly the request's rooms, each technique's; a StoreError naming the run when one is missing."""
    run = Run(request.results, request.run, RUNS)
    manifest = run.manifest()
    rows = []
    for technique in request.techniques:
        model = NAME if technique in LEARNED_SAMPLES else None
        for seed in range(request.first_seed, request.first_seed + request.episodes):
            case = {"technique": technique, "model": model, "seed": seed}
            row = run.find(case, RUNS.expected(manifest, case))
            if row is None:
                raise StoreError(f"{shown(run.dir)}: holds no episode {case}")
            rows.append(row)
    return rows


def results_table(summary: list[dict], command: str) -> list[str]:
    """The techniques' success rates as a Markdown table, under the command that played them."""
    lines = [
        f"Each technique over the same rooms (`{command}`): success rate ± its standard error, deaths, mean steps "
        "to the goal and the median ms of a decision.",
        "",
        "| technique | rooms | success | deaths | steps to the goal | ms a decision |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for r in summary:
        steps = "–" if r["steps"] is None else f"{r['steps']:g}"
        lines.append(
            f"| {r['technique']} | {r['episodes']} | {r['success']:.2f} ± {r['se']:.2f} | {r['deaths']} | {steps} "
            f"| {r['decision_ms']:g} |"
        )
    return [*lines, ""]


#: The command that plays the committed MiniGrid evaluation (every technique over 200 rooms from 1,000,000).
EVALUATION_COMMAND = "python -m flows.evaluate --world minigrid --workers 1"

#: What a MiniGrid agent is given, and so what its success measures: the section's first paragraph.
GIVEN = (
    "Given: the agent's rule (MiniGrid's moves, judged by the paper's collision rule: docs/minigrid.md) and the room "
    "now. Every step each of the 8 balls walks to a random free cell beside it, so no technique but the oracle knows "
    "the future: `walk` samples the balls' true move rule, the learned techniques sample a world model that learned "
    "the rooms from the frames of rooms 0 … 999 (none of these), `stand_still` and `constant_velocity` guess one "
    "future; all plan with the same search (k = 5)."
)


def results_section(results: str | os.PathLike, run: str = "evaluation") -> list[str]:
    """The results page's MiniGrid section from the run of the store at `results` (none if the run is not there)."""
    if not Run(results, run, RUNS).exists():
        return []
    summary = summarise(Run(results, run, RUNS).current())
    return ["## MiniGrid Dynamic-Obstacles", "", GIVEN, "", *results_table(summary, EVALUATION_COMMAND)]


class Stages:
    """MiniGrid's part of `collect-train-eval`: every technique's rooms into one run named by the preset (a learned
    row records the weights it played with, so new weights play again); the report's table of exactly the plan's
    rooms and the learned agent's GIF and replay log."""

    def evaluations(self, preset, work: Path) -> list[MiniGridEvaluation]:
        e = preset.evaluation
        return [
            MiniGridEvaluation(
                techniques=e.techniques,
                episodes=e.episodes,
                first_seed=e.first_seed,
                samples=e.samples,
                results=str(work / "results"),
                run=preset.name,
                model_dir=str(work / "models"),
            )
        ]

    def report(self, preset, work: Path, out: Path, command: str) -> list[str]:
        lines = results_table(summarise(planned_rows(self.evaluations(preset, work)[0])), command)
        if preset.learned_techniques:
            gif = draw_episode(out, work / "models", preset.evaluation)
            lines += [
                f"The {preset.learned_techniques[0]} agent's first room (the room now with the agent | the true room "
                "k steps on | a room the world model imagined there | its chance of a ball in each cell); its "
                f"replay log is `{LOG_NAME}` (`python -m flows.view {LOG_NAME}`):",
                "",
                f"![episode]({gif})",
                "",
            ]
        return lines
