"""Torch datasets over a Zarr store: single frames (for the VQ-VAE) and windows of consecutive frames (4 of
context + 1 target, for the PixelCNN; a longer context repeats frame 0 before the episode's start, as
`dynplan.data.history` says), split by episode into train and validation.

The split is a pure function of each episode's seed, so it never changes as the store grows and an episode is
never in both splits: a world with few episodes names its validation seeds, and those no model trains on, in its
spec (`dynplan.world`); the others' are drawn by a hash of the seed. Episodes are read whole (one Zarr
chunk) and kept in memory once read; frames are checked as they are read (a missing chunk, a pixel value outside the
world's: `dynplan.data.contents`), so no model trains on what is not an episode.
"""

from __future__ import annotations

import os
from typing import Literal

import numpy as np
import torch
import zarr
from torch.utils.data import Dataset

from dynplan.data.chunks import check_present, read
from dynplan.data.contents import seed_check, store_checks
from dynplan.data.history import context_indices, first_target
from dynplan.data.store import store_world
from dynplan.world import World, world

Split = Literal["train", "validation", "all"]
#: Frames of context a window gives before its target (docs/protocol.md §2: the PixelCNN conditions on the last 4).
CONTEXT = 4


def is_validation(seeds: np.ndarray, val_fraction: float) -> np.ndarray:
    """Deterministic per-seed assignment to the validation split (a multiplicative hash of the seed)."""
    if not 0.0 <= val_fraction < 1.0:
        raise ValueError(f"val_fraction must be in [0, 1), got {val_fraction}")
    hashed = (np.asarray(seeds, dtype=np.uint64) * np.uint64(0x9E3779B97F4A7C15)) >> np.uint64(11)
    return hashed.astype(np.float64) / 2.0**53 < val_fraction


def split_of(entry: World, seeds: np.ndarray, val_fraction: float) -> tuple[np.ndarray, np.ndarray]:
    """Which episodes of `entry`'s world, by seed, are validation episodes and which no model trains on."""
    seeds = np.asarray(seeds)
    if entry.validation_seeds is None:
        return is_validation(seeds, val_fraction), np.zeros(len(seeds), bool)
    return np.isin(seeds, list(entry.validation_seeds)), np.isin(seeds, list(entry.held_out_seeds))


class _EpisodeArray(Dataset):
    """Shared loading: which episodes of `array` are in the split, each read once on first use. "all" is every
    episode a model may see: the training and validation episodes, not those of the world's held out."""

    def __init__(
        self, store: str | os.PathLike, split: Split = "train", val_fraction: float = 0.1, array: str = "frames"
    ):
        if split not in ("train", "validation", "all"):
            raise ValueError(f"split must be 'train', 'validation' or 'all', got {split!r}")
        group = zarr.open_group(str(store), mode="r", use_consolidated=False)  # arrays may be growing
        if array not in group:
            raise KeyError(f"{store}: no array {array!r} (has {sorted(group.array_keys())})")
        self.store, self.array = str(store), group[array]
        n_episodes = int(group.attrs.get("episodes", 0))  # committed episodes (arrays may run longer)
        n_episodes = min(n_episodes, int(self.array.attrs.get("episodes", n_episodes)))  # e.g. codes not yet built
        entry = world(store_world(dict(group.attrs)))
        self.seeds = read(
            self.store, group["seed"], slice(0, n_episodes), check=seed_check(*entry.seeds)
        )  # they split it
        validation, held_out = split_of(entry, self.seeds[:n_episodes], val_fraction)
        self._check = store_checks(entry, dict(group.attrs), self.seeds).get(array)  # frames: their seeds' too
        keep = {"train": ~validation & ~held_out, "validation": validation, "all": ~held_out}[split]
        self.episodes = np.nonzero(keep)[0]
        self.n_frames = self.array.shape[1]
        self._check_present(n_episodes)
        self._cache: dict[int, np.ndarray] = {}

    def _check_present(self, n_episodes: int) -> None:
        """A ChunkError before any training if a chunk of the split's episodes is missing (Zarr would give blank
        frames for it)."""
        for episode in self.episodes:
            check_present(self.store, self.array, range(episode, episode + 1))

    def episode(self, i: int) -> np.ndarray:
        """All frames (T, …) of the split's i-th episode (read on first use, then kept)."""
        episode = int(self.episodes[i])
        if episode not in self._cache:
            self._cache[episode] = self.read_episode(i)
        return self._cache[episode]

    def read_episode(self, i: int) -> np.ndarray:
        """The split's i-th episode read from the store, checked (a ChunkError naming it where it is damaged), not
        kept: for a caller that keeps its own copy."""
        episode = int(self.episodes[i])
        describe = lambda rows: f"episode {episode}, seed {self.seeds[episode]}"  # noqa: E731
        return read(self.store, self.array, episode, describe, self._check)


class FrameDataset(_EpisodeArray):
    """Single frames: item → uint8 tensor (H, W) (or a code grid (h, w) with array="codes")."""

    def __len__(self) -> int:
        return len(self.episodes) * self.n_frames

    def __getitem__(self, index: int) -> torch.Tensor:
        if not 0 <= index < len(self):
            raise IndexError(f"index {index} out of range for {len(self)} frames")
        episode, t = divmod(int(index), self.n_frames)
        return torch.from_numpy(np.array(self.episode(episode)[t]))


class WindowDataset(_EpisodeArray):
    """Windows of one episode: item → (context (context, …), target (…)), the `context` frames before the target
    (`dynplan.data.history`), for every target from `first_target(context)` to the episode's last frame."""

    def __init__(
        self,
        store: str | os.PathLike,
        split: Split = "train",
        val_fraction: float = 0.1,
        array: str = "frames",
        context: int = CONTEXT,
    ):
        super().__init__(store, split, val_fraction, array)
        if not 1 <= context < self.n_frames:
            raise ValueError(f"context must be in [1, {self.n_frames - 1}], got {context}")
        self.context = context
        self.first_target = first_target(context)
        self.per_episode = self.n_frames - self.first_target

    def __len__(self) -> int:
        return len(self.episodes) * self.per_episode

    def target(self, index: int) -> tuple[int, int]:
        """(the split's episode position, the target's frame index) of window `index`."""
        if not 0 <= index < len(self):
            raise IndexError(f"index {index} out of range for {len(self)} windows")
        episode, offset = divmod(int(index), self.per_episode)
        return episode, self.first_target + offset

    def __getitem__(self, index: int) -> tuple[torch.Tensor, torch.Tensor]:
        episode, target = self.target(index)
        frames = self.episode(episode)
        history = frames[context_indices(target, self.context)]
        return torch.from_numpy(np.array(history)), torch.from_numpy(np.array(frames[target]))
