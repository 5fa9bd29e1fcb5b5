"""MiniGrid Dynamic-Obstacles as a dynplan world: a room whose balls walk at random, a goal in its corner.

The world is Farama's `minigrid` (the `minigrid` extra) recorded without the agent (`grid`): its future is
genuinely uncertain — every ball moves each step to one of about seven free neighbours — so planning against
sampled futures can beat planning against one guess. `parts` names what the world brings above its frames.
"""

from __future__ import annotations

from dynplan.world import World
from dynplan.worlds.minigrid import grid


def _rebuild(config, seed, frames, goal, agent_start) -> grid.MiniGridWorld:
    return grid.MiniGridWorld(config, seed, frames, goal, agent_start)


WORLD = World(
    name="minigrid",
    summary="MiniGrid Dynamic-Obstacles (16 × 16): balls in a random walk, a goal in the corner",
    config_type=grid.MiniGridConfig,
    recording=grid.MiniGridConfig(),
    seeds=(0, 2**62),
    seed_is="the seed of the room's generator (its balls' placement and walk)",
    record=grid.record_world,
    rebuild=_rebuild,
    pixel_values=lambda config: dict(grid.PIXEL_VALUES),
    has_goal=True,
    actions=grid.ACTIONS,
    clear=(grid.PIXEL_VALUES["floor"], grid.PIXEL_VALUES["goal"]),
    parts="dynplan.worlds.minigrid.parts:PARTS",
    models="dynplan.worlds.minigrid.models",
    extra="minigrid",
)
