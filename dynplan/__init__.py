"""dynplan: planning in dynamic worlds with learned, conditional autoregressive world models.

Importing dynplan registers the Gymnasium environment `dynplan/Road-v0`.
"""

import gymnasium

from dynplan.env import RoadConfig, RoadEnv, World, generate_world
from dynplan.version import __version__

__all__ = ["RoadConfig", "RoadEnv", "World", "__version__", "generate_world"]

if "dynplan/Road-v0" not in gymnasium.registry:
    gymnasium.register(id="dynplan/Road-v0", entry_point="dynplan.env.road_env:RoadEnv")
