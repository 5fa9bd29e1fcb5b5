"""The learned world model: the VQ-VAE tokenizer (stage 1) and the conditional PixelCNN prior (stage 2).

`load_vqvae()` returns a trained tokenizer: `encode(frames)` maps uint8 frames (N, H, W) to integer codes
(N, h, w) and `decode(codes)` maps codes back to uint8 mid-point frames on the world's pixel values.
`load_world_model()` returns the learned forward model the planner uses: `predict(observed_frames, k)`.
Checkpoints are read and written by `dynplan.models.checkpoint`.
"""

from __future__ import annotations

import os

from dynplan.models.checkpoint import WEIGHTS, CheckpointError, cached, pretrained_path
from dynplan.models.registry import WORLD_MODELS, WorldModelSpec, register_world_model, world_model_spec
from dynplan.models.vqvae import PRESETS, VQVAE, VQVAEConfig
from dynplan.models.world_model import LearnedWorldModel, load_world_model


def load_vqvae(path: str | os.PathLike | None = None, model: str = "default") -> VQVAE:
    """A trained VQ-VAE: from `path`, or (None) the committed checkpoint of the preset `model` ("default" or
    "paper"), in eval mode; checked first (`checkpoint.verify`) and loaded once per content of the file."""
    if path is None:
        world_model_spec(model)  # an unknown configuration is named with the known ones
        path = pretrained_path("vqvae", model)
        if not path.exists():
            raise CheckpointError(
                f"{path}: no pretrained VQ-VAE '{model}' in this checkout; train one with "
                f"`python -m flows.train vqvae --model {model}` and pass its path"
            )
        return cached("vqvae", path, model)
    return cached("vqvae", path)


__all__ = [
    "PRESETS",
    "VQVAE",
    "WEIGHTS",
    "WORLD_MODELS",
    "LearnedWorldModel",
    "VQVAEConfig",
    "WorldModelSpec",
    "load_vqvae",
    "load_world_model",
    "pretrained_path",
    "register_world_model",
    "world_model_spec",
]
