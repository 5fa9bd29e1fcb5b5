"""dynplan: planning in dynamic worlds with learned, conditional autoregressive world models.

The few entry points a user starts from:

    env = dynplan.make_env(agent_speed=1.0)                  # the Gymnasium road world (dynplan/Road-v0)
    model = dynplan.load_world_model(model="default", samples=5)  # the committed VQ-VAE + PixelCNN
    agent = dynplan.AgentSpec(technique="samples5", model="default", rollout_steps=3)  # one validated agent
    result = dynplan.plan_episode(1_000_000, agent)          # one episode planned by it

Importing dynplan registers the Gymnasium environment `dynplan/Road-v0`.
"""

from dynplan.interrupts import interrupt_while_loading

interrupt_while_loading()  # before any heavy import

from typing import Any

import gymnasium

from dynplan.lazy import lazy_names
from dynplan.version import __version__

#: The public names, each imported from its module when first used: `import dynplan.cli` (what a command's `--help`
#: needs) does not load torch.
_PUBLIC = {
    "RoadConfig": "dynplan.env",
    "RoadEnv": "dynplan.env",
    "World": "dynplan.env",
    "generate_world": "dynplan.env",
    "AgentSpec": "dynplan.evaluation.agent",
    "plan_episode": "dynplan.evaluation.protocol",
    "TECHNIQUES": "dynplan.evaluation.techniques",
    "register_technique": "dynplan.evaluation.techniques",
    "WORLD_MODELS": "dynplan.models.registry",
    "register_world_model": "dynplan.models.registry",
    "load_world_model": "dynplan.models.world_model",
}

if "dynplan/Road-v0" not in gymnasium.registry:
    gymnasium.register(id="dynplan/Road-v0", entry_point="dynplan.env.road_env:RoadEnv")


__getattr__, __dir__ = lazy_names(__name__, _PUBLIC)


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
