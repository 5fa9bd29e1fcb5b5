"""Checkpoints: atomic torch.save, loading that refuses a checkpoint made for another configuration, and the two
stages' loaders. Training writes through `save`; everything that reads weights reads through here."""

from __future__ import annotations

import functools
import hashlib
import json
import os
from pathlib import Path
from typing import Any

import torch

from dynplan.data.store import sha256_file
from dynplan.files import atomic_path

#: Where the committed, pretrained weights live: `<stage>-<configuration>.pt`, each with its model card `.json`.
WEIGHTS = Path(__file__).parent / "weights"
#: The `kind` a checkpoint of each stage records.
VQVAE_KIND = "vqvae"
PIXELCNN_KIND = "pixelcnn"


class CheckpointError(ValueError):
    """A checkpoint cannot be used here; the message names the file and why."""


class UnreadableCheckpoint(CheckpointError):
    """The file is not a checkpoint torch can read (truncated or damaged)."""


def save(path: str | os.PathLike, state: dict[str, Any]) -> Path:
    with atomic_path(path) as tmp:
        torch.save(state, tmp)
    return Path(path)


def load(path: str | os.PathLike, kind: str, config: dict | None = None) -> dict[str, Any]:
    """Load a checkpoint of `kind` ("vqvae", …); if `config` is given it must equal the checkpoint's."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{path}: no such checkpoint")
    try:
        state = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as error:  # torch raises many kinds for a damaged file
        raise UnreadableCheckpoint(f"{path}: not a readable checkpoint ({type(error).__name__}: {error})") from None
    if not isinstance(state, dict) or state.get("kind") != kind:
        found = state.get("kind") if isinstance(state, dict) else type(state).__name__
        raise CheckpointError(f"{path}: holds a {found!r} checkpoint, expected {kind!r}")
    if config is not None and state.get("config") != config:
        differing = sorted(k for k in set(config) | set(state.get("config", {}))
                           if config.get(k) != state.get("config", {}).get(k))  # fmt: skip
        raise CheckpointError(
            f"{path}: was trained with a different configuration (differs in {', '.join(differing)}): "
            f"checkpoint { ({k: state['config'].get(k) for k in differing}) } vs requested "
            f"{ ({k: config.get(k) for k in differing}) }"
        )
    return state


def digest(*parts: Any) -> str:
    """A stable hex key of JSON-serialisable parts (configs, fingerprints, code versions)."""
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()


def load_vqvae_checkpoint(path: str | os.PathLike, config=None):
    """A VQ-VAE from a checkpoint (final or latest), in eval mode; with `config`, it must be the one trained."""
    from dynplan.models.vqvae import VQVAE

    state = load(path, VQVAE_KIND, None if config is None else config.model_dump())
    try:
        return VQVAE.from_checkpoint(state["config"], state["model"]).eval()
    except RuntimeError as error:  # weights of another architecture: name the file and the first mismatch
        raise CheckpointError(
            f"{path}: its weights do not fit the tokenizer its config describes: {str(error).splitlines()[-1].strip()}"
        ) from None


def load_pixelcnn_checkpoint(path: str | os.PathLike, config=None):
    """A PixelCNN prior from a checkpoint (final or latest), in eval mode; with `config`, it must be the one
    trained."""
    from dynplan.models.pixelcnn import ConditionalPixelCNN, PixelCNNConfig

    state = load(path, PIXELCNN_KIND, None if config is None else config.model_dump())
    model = ConditionalPixelCNN(PixelCNNConfig(**state["config"]))
    model.load_state_dict(state["model"])
    return model.eval()


def pretrained_path(stage: str, model: str) -> Path:
    """Path of the committed weights of `stage` ("vqvae" or "pixelcnn") for the configuration `model` (its
    registry entry names them; `<stage>-<model>.pt` for a configuration without committed weights, which then
    does not exist)."""
    from dynplan.models.registry import WORLD_MODELS

    spec = WORLD_MODELS.get(model)
    return WEIGHTS / (spec.weights.get(stage, f"{stage}-{model}.pt") if spec else f"{stage}-{model}.pt")


@functools.cache
def _sha256(path: str, mtime_ns: int, size: int) -> str:
    return sha256_file(path)  # cached per version of the file (the arguments after the path)


def weights_sha256(path: str | os.PathLike) -> str:
    """SHA-256 of a weights file, computed once per version of the file (path, modification time, size)."""
    stat = os.stat(path)
    return _sha256(str(Path(path).resolve()), stat.st_mtime_ns, stat.st_size)


#: (kind, SHA-256 of the file) → the loaded model: one copy per content, however many paths or callers name it.
_LOADED: dict[tuple[str, str], Any] = {}


def cached(kind: str, path: str | os.PathLike):
    """The model in the checkpoint at `path` (`kind` "vqvae" or "pixelcnn"), loaded once per content."""
    if not Path(path).is_file():
        raise CheckpointError(f"{path}: no such checkpoint")
    key = (kind, weights_sha256(path))
    if key not in _LOADED:
        loader = {VQVAE_KIND: load_vqvae_checkpoint, PIXELCNN_KIND: load_pixelcnn_checkpoint}[kind]
        _LOADED[key] = loader(path)
    return _LOADED[key]
