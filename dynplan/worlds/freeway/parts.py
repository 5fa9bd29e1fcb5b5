"""Freeway's `WorldParts`: its presets and evaluation plan, its commands, its pipeline stages and its benchmark."""

from __future__ import annotations

from pathlib import Path

from dynplan.world_parts import WorldParts
from dynplan.worlds.freeway.commands import Evaluate, Play, Replay
from dynplan.worlds.freeway.evaluation import results_section
from dynplan.worlds.freeway.presets import PRESETS, FreewayEvalPlan
from dynplan.worlds.freeway.report import Stages
from dynplan.worlds.freeway.results import RUNS

#: Freeway's Foxglove layouts: the lanes with the chicken, the lanes searched, its view, height, actions and rewards.
LAYOUTS = Path(__file__).with_name("layouts")

PARTS = WorldParts(
    presets=PRESETS,
    evaluation_plan=FreewayEvalPlan,
    evaluate=Evaluate(),
    replay=Replay(),
    play=Play(),
    pipeline=Stages(),
    benches={"freeway": "dynplan.worlds.freeway.bench:bench_freeway"},
    layout=LAYOUTS / "replay.json",
    studio_layout=LAYOUTS / "replay-studio-1.48.json",
    results_section=results_section,
    runs=RUNS,
)
