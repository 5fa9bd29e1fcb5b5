"""The road's `WorldParts`: its presets and evaluation plan (Table 1's cases), its runs of the results store
(`ROAD_RUNS`), its Foxglove layouts, its halves of `flows.evaluate` (`evaluate`), `flows.replay` and `flows.play`
(`commands`) and its part of `collect-train-eval` (`pipeline`)."""

from __future__ import annotations

from dynplan.evaluation.store import ROAD_RUNS
from dynplan.logs.format import REPLAY_LAYOUT, STUDIO_LAYOUT
from dynplan.pipeline.presets import ROAD_PRESETS, EvalPlan
from dynplan.world_parts import WorldParts
from dynplan.worlds.road.commands import Play, Replay
from dynplan.worlds.road.evaluate import Evaluate
from dynplan.worlds.road.pipeline import Stages

PARTS = WorldParts(
    presets=ROAD_PRESETS,
    evaluation_plan=EvalPlan,
    runs=ROAD_RUNS,
    layout=REPLAY_LAYOUT,
    studio_layout=STUDIO_LAYOUT,
    evaluate=Evaluate(),
    replay=Replay(),
    play=Play(),
    pipeline=Stages(),
)
