"""Checkpoints: atomic torch.save, loading that refuses a checkpoint made for another configuration, and the two
stages' loaders. Training writes through `save`; everything that reads weights reads through here."""

from __future__ import annotations

import errno
import hashlib
import json
import os
import shutil
from collections.abc import Collection, Mapping, Sequence
from pathlib import Path
from typing import Any

import torch

from dynplan.cli import InputError
from dynplan.files import atomic_path
from dynplan.models.weights import pretrained_path, weights_sha256

#: The `kind` a checkpoint of each stage records.
VQVAE_KIND = "vqvae"
PIXELCNN_KIND = "pixelcnn"


class CheckpointError(InputError):
    """A checkpoint cannot be used here; the message names the file and why."""


class UnreadableCheckpoint(CheckpointError):
    """The file is not a checkpoint torch can read (truncated or damaged)."""


def tensors_digest(weights: Mapping[str, torch.Tensor]) -> str:
    """SHA-256 of a state dict's names, dtypes, shapes and bytes: what a checkpoint's weights were when saved."""
    hasher = hashlib.sha256()
    for name in sorted(weights):
        tensor = weights[name].detach().cpu().contiguous()
        hasher.update(f"{name}|{tensor.dtype}|{tuple(tensor.shape)}|".encode())
        hasher.update(tensor.reshape(-1).view(torch.uint8).numpy().tobytes())
    return hasher.hexdigest()


def save(path: str | os.PathLike, state: dict[str, Any]) -> Path:
    """Write a checkpoint atomically; one with model weights records their digest (`model_sha256`), so that any
    later change to them is found when it is loaded (`check_digest`)."""
    if isinstance(state.get("model"), Mapping):
        state = {**state, "model_sha256": tensors_digest(state["model"])}
    with atomic_path(path) as tmp:
        try:
            torch.save(state, tmp)
        except RuntimeError as error:  # torch's zip writer reports a failed write as "[enforce fail at …]"
            if "inline_container" not in str(error) and "PytorchStreamWriter" not in str(error):
                raise
            free = shutil.disk_usage(Path(path).parent).free
            why = f"the checkpoint could not be written: {free:,} bytes free there"
            raise OSError(errno.ENOSPC if free < 1 << 20 else errno.EIO, why, str(path)) from error
    return Path(path)


def check_digest(path: str | os.PathLike, state: dict) -> None:
    """A checkpoint that records its weights' digest holds those weights (a flipped byte in a tensor is found)."""
    recorded = state.get("model_sha256")
    if recorded is not None and (
        not isinstance(state.get("model"), Mapping) or tensors_digest(state["model"]) != recorded
    ):
        raise CheckpointError(f"{path}: its weights are not the ones it was saved with (the file is damaged)")


def load(path: str | os.PathLike, kind: str, config: dict | None = None) -> dict[str, Any]:
    """Load a checkpoint of `kind` ("vqvae", …); if `config` is given it must equal the checkpoint's."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{path}: no such checkpoint")
    try:
        state = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as error:  # torch raises many kinds for a damaged file; its first sentence says which
        said = str(error).strip().splitlines()[0].split(". ")[0] if str(error).strip() else ""
        raise UnreadableCheckpoint(f"{path}: not a readable checkpoint ({type(error).__name__}: {said})") from None
    if not isinstance(state, dict) or state.get("kind") != kind:
        found = state.get("kind") if isinstance(state, dict) else type(state).__name__
        raise CheckpointError(f"{path}: holds a {found!r} checkpoint, expected {kind!r}")
    if config is not None and state.get("config") != config:
        differing = sorted(
            k for k in set(config) | set(state.get("config", {})) if config.get(k) != state.get("config", {}).get(k)
        )
        raise CheckpointError(
            f"{path}: was trained with a different configuration (differs in {', '.join(differing)}): "
            f"checkpoint { ({k: state['config'].get(k) for k in differing}) } vs requested "
            f"{ ({k: config.get(k) for k in differing}) }"
        )
    return state


def module_shapes(kind: str, config: Mapping) -> dict[str, tuple[int, ...]]:
    """The tensors (name → shape) a model of `kind` built from `config` holds: built on the meta device, so
    nothing is allocated or initialised. An invalid config is a ConfigError."""
    from dynplan.models.configs import PixelCNNConfig
    from dynplan.models.pixelcnn import ConditionalPixelCNN
    from dynplan.models.vqvae import VQVAE

    with torch.device("meta"):
        if kind == VQVAE_KIND:
            model = VQVAE(VQVAE.recorded_config(dict(config)))
        else:
            model = ConditionalPixelCNN(PixelCNNConfig(**config))
    return {name: tuple(tensor.shape) for name, tensor in model.state_dict().items()}


def model_weights(kind: str, weights: dict, own: Collection[str]) -> dict:
    """A checkpoint's weights as a model of `kind` whose state has the keys `own` takes them (a tokenizer leaves
    out its codebook's training-only statistics: `VQVAE.recorded_weights`)."""
    from dynplan.models.vqvae import VQVAE

    return VQVAE.recorded_weights(weights, own) if kind == VQVAE_KIND else dict(weights)


def _shown(shape: Sequence[int]) -> str:
    return f"({', '.join(map(str, shape))})"


def check_tensors(path: str | os.PathLike, state: dict, kind: str) -> None:
    """A CheckpointError naming the file unless the weights are those of the configuration the checkpoint
    records (the same tensors, of its shapes) and every value is finite."""
    config, weights = state.get("config"), state.get("model")
    if not isinstance(config, dict) or not isinstance(weights, dict):
        raise CheckpointError(f"{path}: holds no configuration and weights ('config' and 'model' dicts)")
    name = config.get("name", "custom")
    try:
        needs = module_shapes(kind, config)
    except (ValueError, TypeError) as error:  # ConfigError: a value out of range, an unknown key; keys not names
        raise CheckpointError(f"{path}: its recorded configuration is invalid: {error}") from None
    weights = model_weights(kind, weights, needs)
    for key, value in weights.items():
        if key not in needs:
            raise CheckpointError(f"{path}: holds tensor {key!r}, which configuration {name!r} does not have")
        if not isinstance(value, torch.Tensor):
            raise CheckpointError(f"{path}: {key!r} is a {type(value).__name__}, not a tensor")
        if tuple(value.shape) != needs[key]:
            raise CheckpointError(
                f"{path}: tensor {key!r} has shape {_shown(value.shape)} but configuration "
                f"{name!r} needs {_shown(needs[key])}"
            )
        if value.is_floating_point() and not bool(torch.isfinite(value).all()):
            raise CheckpointError(f"{path}: tensor {key!r} holds NaN/inf values")
    missing = [key for key in needs if key not in weights]
    if missing:
        raise CheckpointError(
            f"{path}: lacks tensor {missing[0]!r} of shape {_shown(needs[missing[0]])}, which "
            f"configuration {name!r} needs"
        )


def model_card(path: str | os.PathLike) -> tuple[Path, dict] | None:
    """The model card beside the weights at `path` (`<name>.json` holding a `sha256`), as (its path, its
    contents); None without one. A card that is not JSON is a CheckpointError."""
    card = Path(path).with_suffix(".json")
    if not card.is_file():
        return None
    try:
        contents = json.loads(card.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise CheckpointError(f"{card}: the model card of {Path(path).name} is not readable JSON ({error})") from None
    return (card, contents) if isinstance(contents, dict) and "sha256" in contents else None


def _differing(a: Mapping, b: Mapping) -> list[str]:
    a, b = json.loads(json.dumps(a, default=str)), json.loads(json.dumps(b, default=str))  # tuples as lists
    return sorted(k for k in set(a) | set(b) if a.get(k) != b.get(k))


def check_card(path: str | os.PathLike, state: dict, kind: str) -> None:
    """A CheckpointError naming the file unless it is what its model card (if it has one) describes: the card's
    stage, configuration and SHA-256."""
    found = model_card(path)
    if found is None:
        return
    card, contents = found
    if contents.get("stage", kind) != kind:
        raise CheckpointError(
            f"{path}: holds a {kind!r} checkpoint, but its model card {card} describes a {contents['stage']!r} one"
        )
    described = contents.get("config")
    if isinstance(described, dict) and _differing(described, state["config"]):
        ours, theirs = state["config"].get("name", "custom"), described.get("name", "custom")
        if ours != theirs:
            raise CheckpointError(
                f"{path}: its configuration is {ours!r}'s, not {theirs!r}'s (it does not match the model card {card})"
            )
        raise CheckpointError(
            f"{path}: its configuration differs from its model card {card} in "
            f"{', '.join(_differing(described, state['config']))}"
        )
    if contents["sha256"] != weights_sha256(path):
        raise CheckpointError(
            f"{path}: its SHA-256 is not the one its model card {card} records (the file was changed or replaced)"
        )


def check_configuration(path: str | os.PathLike, kind: str, found: str, expected: str) -> None:
    """A CheckpointError naming the file when weights recording the registered configuration `found` are used
    as configuration `expected`'s (a configuration's own variants, with its name, are its own)."""
    from dynplan.models.registry import is_world_model

    if found == expected or not is_world_model(found):
        return
    card = pretrained_path(kind, expected).with_suffix(".json")
    twin = pretrained_path(kind, found)
    same = twin.is_file() and twin.resolve() != Path(path).resolve() and weights_sha256(twin) == weights_sha256(path)
    because = f"it does not match the model card {card.name}" if card.is_file() else f"it records {found!r}"
    raise CheckpointError(
        f"{path}: its configuration is {found!r}'s, not {expected!r}'s ({because}"
        f"{f'; it is a copy of {twin.name}' if same else ''})"
    )


def verify(
    path: str | os.PathLike, kind: str, config: dict | None = None, configuration: str | None = None
) -> dict[str, Any]:
    """Load a checkpoint of `kind` and check it up front, each failure one CheckpointError naming the file: it
    is readable and of `kind` (and of `config`, if given); its tensors are its recorded configuration's, of its
    shapes, and finite; it is what its model card says; and, with `configuration`, it is that registered
    configuration's weights and not another's."""
    state = load(path, kind, config)
    check_digest(path, state)
    check_tensors(path, state, kind)
    check_card(path, state, kind)
    if configuration is not None:
        check_configuration(path, kind, state["config"].get("name", "custom"), configuration)
    return state


def warm_weights(path: str | os.PathLike, state: dict, kind: str, target: Mapping[str, Sequence[int]]) -> dict:
    """The checkpoint's weights as a warm start of a model whose tensors have the shapes `target` (name →
    shape): the same shapes, or grown along one dimension (a larger codebook); a decoder's calibration added
    (scale 1) or dropped as the target has it. Anything else is a CheckpointError naming the file."""
    source = model_weights(kind, state["model"], target)
    if "code_sharpness" in target and "code_sharpness" not in source:  # from an uncalibrated decoder: scale 1
        source["code_sharpness"] = torch.ones(tuple(target["code_sharpness"]))
    source = {k: v for k, v in source.items() if k != "code_sharpness" or k in target}
    if set(source) != set(target):
        differing = ", ".join(sorted(set(source) ^ set(target))[:4])
        raise CheckpointError(
            f"{path}: cannot start this run from it: the architecture differs (parameters {differing} …)"
        )
    for name, value in source.items():
        into = tuple(target[name])
        grown = [d for d in range(len(into)) if into[d] != value.shape[d]] if len(into) == value.dim() else None
        if grown is None or len(grown) > 1 or (grown and into[grown[0]] < value.shape[grown[0]]):
            raise CheckpointError(
                f"{path}: cannot start this run from it: the architecture differs ({name}: "
                f"{tuple(value.shape)} vs {into})"
            )
    return source


def load_vqvae_checkpoint(path: str | os.PathLike, config=None, configuration: str | None = None):
    """A VQ-VAE from a checkpoint (final or latest), in eval mode, its weights checked first (`verify`); with
    `config`, it must be the one trained; with `configuration`, the registered configuration it must be."""
    from dynplan.models.vqvae import VQVAE

    state = verify(path, VQVAE_KIND, None if config is None else config.model_dump(), configuration)
    return VQVAE.from_checkpoint(state["config"], state["model"]).eval()


def load_pixelcnn_checkpoint(path: str | os.PathLike, config=None, configuration: str | None = None):
    """A PixelCNN prior from a checkpoint (final or latest), in eval mode, checked as `load_vqvae_checkpoint`'s."""
    from dynplan.models.configs import PixelCNNConfig
    from dynplan.models.pixelcnn import ConditionalPixelCNN

    state = verify(path, PIXELCNN_KIND, None if config is None else config.model_dump(), configuration)
    model = ConditionalPixelCNN(PixelCNNConfig(**state["config"]))
    model.load_state_dict(state["model"])
    return model.eval()


#: (kind, SHA-256 of the file) → the loaded model: one copy per content, however many paths or callers name it.
_LOADED: dict[tuple[str, str], Any] = {}


def cached(kind: str, path: str | os.PathLike, configuration: str | None = None):
    """The model in the checkpoint at `path` (`kind` "vqvae" or "pixelcnn"), checked (`verify`) and loaded once
    per content; with `configuration`, it must be that registered configuration's weights (checked every time)."""
    if not Path(path).is_file():
        raise CheckpointError(f"{path}: no such checkpoint")
    key = (kind, weights_sha256(path))
    if key not in _LOADED:
        loader = {VQVAE_KIND: load_vqvae_checkpoint, PIXELCNN_KIND: load_pixelcnn_checkpoint}[kind]
        _LOADED[key] = loader(path)
    if configuration is not None:
        check_configuration(path, kind, _LOADED[key].config.name, configuration)
    return _LOADED[key]
