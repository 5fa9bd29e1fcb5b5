"""MiniGrid's world model: a tokenizer of one code a cell and a prior of the next room, registered with the world-model
configurations.

The room is 16 × 16 cells of 4 contents, so the tokenizer is the patch-local, content-fitted autoencoder with 2 × 2
patches: an 8 × 8 grid of codes, each of the 38 distinct patches of the rooms a code of its own (exact; 64 codes).
The prior learns the balls' walk from the frames alone: conditioned on the last 2 grids (enough to learn that a
ball's step does not depend on its last), it draws the next grid code by code, so the balls' joint move (none onto
another) is one sample; narrow (16 channels, 4 layers, 64 positions a grid) so that a decision's futures —
samples × horizon grids — fit in tens of milliseconds. The committed weights trained on rooms 0 … 999 (the model
cards beside them hold the commands and the held-out metrics).
"""

from __future__ import annotations

from pathlib import Path

from dynplan.models.configs import PixelCNNConfig, VQVAEConfig
from dynplan.models.registry import WORLD_MODELS, WorldModelSpec, register_world_model

#: The configuration's name: the world's own.
NAME = "minigrid"

TOKENIZER = VQVAEConfig(
    name=NAME,
    world="minigrid",
    height=16,
    width=16,
    channels=(16,),
    strides=(2,),
    residual_blocks=0,
    latent_dim=8,
    codebook_size=64,
    likelihood="categorical",
    goal_weight=1.0,
    learning_rate=1e-3,
    batch_size=256,
    local=True,
    codebook_fit="contents",
    calibrate_decoder=False,
)
PRIOR = PixelCNNConfig(
    name=NAME,
    codebook_size=64,
    context=2,
    channels=16,
    layers=4,
    first_kernel=5,
    embed_dim=8,
    condition_channels=32,
    codebook_init=True,
    batch_size=64,
    learning_rate=1e-3,
)
CONFIGURATION = WorldModelSpec(
    NAME,
    TOKENIZER,
    PRIOR,
    budgets={
        "vqvae": {"epochs": 4, "steps_per_epoch": 500},
        "pixelcnn": {"epochs": 20, "steps_per_epoch": 500, "threads": 1},
    },
    weights={"vqvae": "vqvae-minigrid.pt", "pixelcnn": "pixelcnn-minigrid.pt"},
    description="MiniGrid's: one code a cell (4 contents), the next room drawn cell by cell from the last 2",
    weights_dir=Path(__file__).with_name("weights"),
)

if NAME not in WORLD_MODELS:
    register_world_model(CONFIGURATION)
