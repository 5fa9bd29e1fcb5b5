"""Checkpoints: atomic torch.save, and loading that refuses a checkpoint made for another configuration."""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any

import torch

from dynplan.files import atomic_path


class CheckpointError(ValueError):
    """A checkpoint cannot be used here; the message names the file and why."""


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
        raise CheckpointError(f"{path}: not a readable checkpoint ({type(error).__name__}: {error})") from None
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
