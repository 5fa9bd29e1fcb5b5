"""The road world (docs/protocol.md §1): config, vectorised episode generation, agent rules and the Gymnasium env."""

from dynplan.env.agent import (
    ACTION_ANGLES_DEG,
    FIRST_DECISION_FRAME,
    N_ACTIONS,
    Outcome,
    action_deltas,
    judge,
    reward_of,
)
from dynplan.env.config import GOAL_VALUE, RoadConfig, episode_frames, obstacle_classes
from dynplan.env.road import World, generate_world, round_px
from dynplan.env.road_env import RoadEnv

__all__ = [
    "ACTION_ANGLES_DEG",
    "FIRST_DECISION_FRAME",
    "GOAL_VALUE",
    "N_ACTIONS",
    "Outcome",
    "RoadConfig",
    "RoadEnv",
    "World",
    "action_deltas",
    "episode_frames",
    "generate_world",
    "judge",
    "obstacle_classes",
    "reward_of",
    "round_px",
]
