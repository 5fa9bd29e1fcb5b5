"""The road's `WorldParts`: its presets and evaluation plan (Table 1's cases), its runs of the results store
(`ROAD_RUNS`), its Foxglove layouts and its half of `flows.replay` (`commands`). Its evaluate and play commands are
still the flows' own (`flows.evaluate`, `flows.play` without `--world`), over `dynplan.evaluation`."""

from __future__ import annotations

from dynplan.evaluation.store import ROAD_RUNS
from dynplan.logs.format import REPLAY_LAYOUT, STUDIO_LAYOUT
from dynplan.pipeline.presets import ROAD_PRESETS, EvalPlan
from dynplan.world_parts import WorldParts
from dynplan.worlds.road.commands import Replay

PARTS = WorldParts(
    presets=ROAD_PRESETS,
    evaluation_plan=EvalPlan,
    runs=ROAD_RUNS,
    layout=REPLAY_LAYOUT,
    studio_layout=STUDIO_LAYOUT,
    replay=Replay(),
)
