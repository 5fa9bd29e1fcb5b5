"""MiniGrid's `WorldParts`: its evaluation (`commands.Evaluate`) and its runs of the results store
(`results.RUNS`)."""

from __future__ import annotations

from dynplan.world_parts import WorldParts
from dynplan.worlds.minigrid.commands import Evaluate
from dynplan.worlds.minigrid.results import RUNS

PARTS = WorldParts(evaluate=Evaluate(), runs=RUNS)
