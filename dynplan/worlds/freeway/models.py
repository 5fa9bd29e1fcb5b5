"""Freeway's world model: its tokenizer and lane-strip prior, registered with the world-model configurations.

The tokenizer is the default's patch-local, content-fitted codes on Freeway's lanes (154 × 152, 14 values,
docs/worlds.md), the frame padded with 6 rows of road above so that code rows 4i … 4i + 3 are lane i (a 40 × 38
grid); 640 codes hold every distinct 4 × 4 patch of the training modes (627); no goal to weigh. The prior models
the grid as 10 lane strips of 4 × 38 codes, generated together: 152 positions in sequence a grid instead of 1,520.
Narrow (16 channels, 4 layers: 13 ms a grid on one core) with a wide conditioning kernel (3 × 7 codes, twice: ±12
codes, 48 px) that sees a car's last 4 positions at 4 px a step.
"""

from __future__ import annotations

from pathlib import Path

from dynplan.models.configs import PRESETS, PixelCNNConfig, VQVAEConfig
from dynplan.models.registry import WORLD_MODELS, WorldModelSpec, register_world_model

#: The configuration's name: the world's own.
NAME = "freeway"

TOKENIZER = VQVAEConfig.from_dict(
    PRESETS["default"].model_dump(),
    name=NAME,
    world="freeway",
    height=154,
    width=152,
    pad_top=6,
    codebook_size=640,
    goal_weight=1.0,
)
PRIOR = PixelCNNConfig(
    name=NAME,
    codebook_size=640,
    channels=16,
    layers=4,
    first_kernel=5,
    embed_dim=16,
    condition_channels=64,
    condition_width=7,
    strip_rows=4,
    codebook_init=True,
    batch_size=64,
    learning_rate=1e-3,
)
CONFIGURATION = WorldModelSpec(
    NAME,
    TOKENIZER,
    PRIOR,
    budgets={
        "vqvae": {"epochs": 24, "steps_per_epoch": 1000},
        "pixelcnn": {"epochs": 10, "steps_per_epoch": 500, "threads": 2},
    },
    weights={"vqvae": "vqvae-freeway.pt", "pixelcnn": "pixelcnn-freeway.pt"},
    description="Atari Freeway's: 40 × 38 patch-local codes from 640, the prior over lane strips of 4 × 38",
    weights_dir=Path(__file__).with_name("weights"),
)

if NAME not in WORLD_MODELS:
    register_world_model(CONFIGURATION)
