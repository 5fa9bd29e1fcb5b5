"""Where a world-model configuration's weights are and what they are: the committed weights' folder (`WEIGHTS`),
a configuration's checkpoint paths (`pretrained_path`, `world_model_paths`) and a weights file's SHA-256
(`weights_sha256`). Apart from the checkpoints' reading (`checkpoint.py`) so that a manifest or a command can name
and hash weights without importing torch.
"""

from __future__ import annotations

import functools
import os
from pathlib import Path

from dynplan.files import sha256_file
from dynplan.models.registry import is_world_model, world_model_spec

#: Where the committed, pretrained weights live: `<stage>-<configuration>.pt`, each with its model card `.json`.
WEIGHTS = Path(__file__).parent / "weights"


def pretrained_path(stage: str, model: str) -> Path:
    """Path of the committed weights of `stage` ("vqvae" or "pixelcnn") for the configuration `model` (its
    registry entry names them; `<stage>-<model>.pt` for a configuration without committed weights, which then
    does not exist)."""
    if not is_world_model(model):
        return WEIGHTS / f"{stage}-{model}.pt"
    spec = world_model_spec(model)
    return (spec.weights_dir or WEIGHTS) / spec.weights.get(stage, f"{stage}-{model}.pt")


@functools.cache
def _sha256(path: str, mtime_ns: int, size: int) -> str:
    return sha256_file(path)  # cached per version of the file (the arguments after the path)


def weights_sha256(path: str | os.PathLike) -> str:
    """SHA-256 of a weights file, computed once per version of the file (path, modification time, size)."""
    stat = os.stat(path)
    return _sha256(str(Path(path).resolve()), stat.st_mtime_ns, stat.st_size)


def world_model_paths(model: str, model_dir: str | os.PathLike | None = None) -> tuple[Path, Path]:
    """The (VQ-VAE, PixelCNN) checkpoints of configuration `model`: `model_dir/<model>/{vqvae,pixelcnn}.pt` when a
    pipeline trained its own, else the committed pretrained ones."""
    if model_dir is not None:
        return Path(model_dir) / model / "vqvae.pt", Path(model_dir) / model / "pixelcnn.pt"
    return pretrained_path("vqvae", model), pretrained_path("pixelcnn", model)
