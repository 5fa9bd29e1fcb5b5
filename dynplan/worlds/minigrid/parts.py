"""MiniGrid's `WorldParts`: its presets and evaluation plan, its evaluation and play window (`commands`), its
pipeline stages (`report`) and its runs of the results store (`results.RUNS`)."""

from __future__ import annotations

from pathlib import Path

from dynplan.world_parts import WorldParts
from dynplan.worlds.minigrid.commands import Evaluate, Play, Replay
from dynplan.worlds.minigrid.presets import PRESETS, MiniGridEvalPlan
from dynplan.worlds.minigrid.report import Stages, results_section
from dynplan.worlds.minigrid.results import RUNS

#: MiniGrid's Foxglove layouts: the room with the agent, the room the planner searched, its view, path and steps.
LAYOUTS = Path(__file__).with_name("layouts")

PARTS = WorldParts(
    presets=PRESETS,
    evaluation_plan=MiniGridEvalPlan,
    evaluate=Evaluate(),
    replay=Replay(),
    play=Play(),
    pipeline=Stages(),
    benches={"minigrid": "dynplan.worlds.minigrid.bench:bench_minigrid"},
    layout=LAYOUTS / "replay.json",
    studio_layout=LAYOUTS / "replay-studio-1.48.json",
    results_section=results_section,
    runs=RUNS,
)
