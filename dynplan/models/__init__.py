"""The learned world model: the VQ-VAE tokenizer (stage 1) and the conditional PixelCNN prior (stage 2).

`load_vqvae()` returns a trained tokenizer: `encode(frames)` maps uint8 frames (N, H, W) to integer codes
(N, h, w) and `decode(codes)` maps codes back to uint8 mid-point frames on the world's pixel values.
`load_world_model()` returns the learned forward model the planner uses: `predict(context, k, samples)`.
"""

from __future__ import annotations

import os
from pathlib import Path

from dynplan.models.vqvae import PRESETS, VQVAE, VQVAEConfig

#: Where the committed, pretrained checkpoints live (one per preset: vqvae-default.pt, vqvae-paper.pt).
WEIGHTS = Path(__file__).parent / "weights"


def pretrained_path(stage: str, model: str) -> Path:
    """Path of the committed checkpoint of `stage` ("vqvae", …) for the preset `model`."""
    return WEIGHTS / f"{stage}-{model}.pt"


def load_vqvae(path: str | os.PathLike | None = None, model: str = "default") -> VQVAE:
    """A trained VQ-VAE: from `path`, or (None) the committed checkpoint of the preset `model` ("default" or
    "paper"), in eval mode."""
    from dynplan.training.checkpoint import CheckpointError
    from dynplan.training.vqvae import load_vqvae_checkpoint

    if path is None:
        if model not in PRESETS:
            raise ValueError(f"model must be one of {sorted(PRESETS)}, got {model!r}")
        path = pretrained_path("vqvae", model)
        if not path.exists():
            raise CheckpointError(
                f"{path}: no pretrained VQ-VAE '{model}' in this checkout; train one with "
                f"`python -m flows.train vqvae --model {model}` and pass its path"
            )
    return load_vqvae_checkpoint(path)


def __getattr__(name: str):
    # The forward model imports the training code, which imports this package: load it on first use.
    if name in ("load_world_model", "LearnedWorldModel"):
        from dynplan.models import world_model

        return getattr(world_model, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["PRESETS", "VQVAE", "LearnedWorldModel", "VQVAEConfig", "load_vqvae", "load_world_model", "pretrained_path"]
