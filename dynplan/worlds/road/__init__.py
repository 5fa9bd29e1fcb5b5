"""The road world (the paper's, and the default): lanes of traffic and a wall-bouncing goal, 48 × 48.

Its frames, agent and planner live in `dynplan.env`, `dynplan.planning` and `dynplan.evaluation`; this spec names
them for the registry (`dynplan.world`), and `parts` the rest.
"""

from __future__ import annotations

from dynplan.env.agent import ACTION_ANGLES_DEG
from dynplan.env.config import FREE, GOAL_VALUE, RoadConfig, obstacle_classes
from dynplan.env.road import World as RoadWorld
from dynplan.env.road import generate_world
from dynplan.world import World


def road_pixel_values(config: RoadConfig) -> dict[str, int]:
    """The road's values by name: free road, the goal and each obstacle class of its width."""
    return {"free": FREE, "goal": GOAL_VALUE, **{c.name: c.value for c in obstacle_classes(config.width)}}


def _rebuild(config, seed, frames, goal, agent_start) -> RoadWorld:
    return RoadWorld(config, seed, frames, goal, agent_start)


WORLD = World(
    name="road",
    summary="the paper's world: lanes of traffic and a wall-bouncing goal, 48 × 48",
    config_type=RoadConfig,
    recording=RoadConfig(level=6, agent_speed=0.5),
    seeds=(0, 2**62),
    seed_is="the seed of the episode's random draws",
    record=generate_world,
    rebuild=_rebuild,
    pixel_values=road_pixel_values,
    has_goal=True,
    actions=tuple(f"heading {angle:g}°" for angle in ACTION_ANGLES_DEG),
    clear=(FREE, GOAL_VALUE),
    parts="dynplan.worlds.road.parts:PARTS",
)
