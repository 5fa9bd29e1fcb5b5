"""MiniGrid's `WorldParts`: its evaluation and play window (`commands`) and its runs of the results store
(`results.RUNS`)."""

from __future__ import annotations

from dynplan.world_parts import WorldParts
from dynplan.worlds.minigrid.commands import Evaluate, Play
from dynplan.worlds.minigrid.results import RUNS

PARTS = WorldParts(evaluate=Evaluate(), play=Play(), runs=RUNS)
