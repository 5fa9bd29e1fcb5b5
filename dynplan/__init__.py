"""dynplan: planning in dynamic worlds with learned, conditional autoregressive world models.

The few entry points a user starts from:

    env = dynplan.make_env(agent_speed=1.0)                  # the Gymnasium road world (dynplan/Road-v0)
    model = dynplan.load_world_model(model="default", samples=5)  # the committed VQ-VAE + PixelCNN
    agent = dynplan.AgentSpec(technique="samples5", model="default", rollout_steps=3)  # one validated agent
    result = dynplan.plan_episode(1_000_000, agent)          # one episode planned by it

Importing dynplan registers the Gymnasium environment `dynplan/Road-v0`.
"""

from dynplan.cli import interrupt_while_loading

interrupt_while_loading()  # before the heavy imports below

from typing import Any

import gymnasium

from dynplan.env import RoadConfig, RoadEnv, World, generate_world
from dynplan.evaluation.agent import AgentSpec
from dynplan.evaluation.protocol import plan_episode
from dynplan.evaluation.techniques import TECHNIQUES, register_technique
from dynplan.models.registry import WORLD_MODELS, register_world_model
from dynplan.models.world_model import load_world_model
from dynplan.version import __version__

if "dynplan/Road-v0" not in gymnasium.registry:
    gymnasium.register(id="dynplan/Road-v0", entry_point="dynplan.env.road_env:RoadEnv")


def make_env(**kwargs: Any) -> gymnasium.Env:
    """`gymnasium.make("dynplan/Road-v0", **kwargs)`: e.g. `agent_speed=1.0, level=6, render_mode="rgb_array"`."""
    return gymnasium.make("dynplan/Road-v0", **kwargs)


__all__ = [
    "TECHNIQUES",
    "WORLD_MODELS",
    "AgentSpec",
    "RoadConfig",
    "RoadEnv",
    "World",
    "__version__",
    "generate_world",
    "load_world_model",
    "make_env",
    "plan_episode",
    "register_technique",
    "register_world_model",
]
