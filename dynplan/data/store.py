"""The frames store: recorded episodes as a chunked Zarr v3 group, built from logs with dask.

Layout (readable with `zarr`, `dask.array.from_zarr` or `xarray.open_zarr`, no dynplan needed):

| array      | shape                        | dtype   | chunks         | dimension_names              |
| ---------- | ---------------------------- | ------- | -------------- | ---------------------------- |
| frames     | (episode, time, y, x)        | uint8   | one episode    | episode, time, y, x          |
| goal       | (episode, time, 2)           | float64 | 64 episodes    | episode, time, yx (a world with a goal) |
| seed       | (episode,)                   | int64   | 1024           | episode                      |
| log_name   | (episode,)                   | string  | 1024           | episode                      |
| log_sha256 | (episode,)                   | string  | 1024           | episode                      |

Group attributes hold the format, the world (`world`, absent for the road, the first world) and its config,
n_frames, height, width and the pixel-value legend.
Row 0 of `y` is the bottom of the world. Every chunk carries a CRC-32C (`dynplan.data.chunks`).

Appending is incremental: logs whose SHA-256 is already in `log_sha256` are skipped (and their episodes checked,
and repaired from those logs if damaged), new ones are appended in (seed, name) order; replays and a second log of
a seed already in are refused. New rows are written before the arrays grow, and the group attribute `episodes`,
written after each batch, is the store's commit record: an append interrupted between growing one array and the
next leaves arrays of different lengths, each holding complete rows only, and the next build truncates them back
to it. One build or repair at a time holds the store's lock (`<store>.lock`, beside it); another waits, saying so.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import zarr
from zarr.core.buffer import default_buffer_prototype
from zarr.storage import MemoryStore

from dynplan.data.chunks import COMPRESSORS, read
from dynplan.files import sha256_file
from dynplan.logs.reader import LogError, read_episode_log
from dynplan.world import DEFAULT_WORLD, world

STORE_FORMAT = "dynplan.frames"
#: 2: checksummed chunks; 1 (without checksums) is read but no longer extended.
STORE_VERSION = "2"
#: Episodes per chunk of `goal`, and appended per dask computation (bounds memory: 64 × 407 × 48 × 48 B ≈ 60 MB).
BATCH_EPISODES = 64

#: Every array of episodes a store may hold; a world without a goal has no `goal` (`store_arrays`).
ARRAYS = ("frames", "goal", "seed", "log_name", "log_sha256")
#: The group attribute `y_axis`.
Y_AXIS = "row 0 is the bottom of the world"


def store_arrays(world_name: str = DEFAULT_WORLD) -> tuple[str, ...]:
    """The arrays of episodes a store of the world `world_name` holds."""
    return ARRAYS if world(world_name).has_goal else tuple(name for name in ARRAYS if name != "goal")


def store_world(attributes: dict) -> str:
    """The world a store's group attributes name (the road where they name none)."""
    return attributes.get("world", DEFAULT_WORLD)


def array_specs(n_frames: int, height: int, width: int) -> dict[str, dict]:
    """The format of each array a store of episodes of `n_frames` frames of height × width may hold, with no rows:
    `zarr.create_array` arguments besides the codecs (`COMPRESSORS`)."""
    T, H, W = n_frames, height, width
    strings = {"shape": (0,), "chunks": (1024,), "dtype": str, "dimension_names": ("episode",)}
    return {
        "frames": {
            "shape": (0, T, H, W),
            "chunks": (1, T, H, W),
            "dtype": "uint8",
            "dimension_names": ("episode", "time", "y", "x"),
        },
        "goal": {
            "shape": (0, T, 2),
            "chunks": (BATCH_EPISODES, T, 2),
            "dtype": "float64",
            "dimension_names": ("episode", "time", "yx"),
        },
        "seed": {**strings, "dtype": "int64"},
        "log_name": strings,
        "log_sha256": strings,
    }


def format_metadata(name: str, rows: int, geometry: tuple[int, int, int], attributes: dict | None = None) -> bytes:
    """The `zarr.json` the format gives the array `name` with `rows` episodes of `geometry` (T, H, W), byte for
    byte as a build writes it."""
    spec = array_specs(*geometry)[name]
    return spec_metadata({**spec, "shape": (rows, *spec["shape"][1:])}, attributes)


def spec_metadata(spec: dict, attributes: dict | None = None) -> bytes:
    """The `zarr.json` of an array made by `zarr.create_array(**spec)` with the store's codecs."""
    array = zarr.create_array(MemoryStore(), compressors=COMPRESSORS, attributes=attributes or {}, **spec)
    return metadata_bytes(array.metadata)


def metadata_bytes(metadata) -> bytes:
    """An array's metadata as Zarr writes it to its `zarr.json`."""
    return metadata.to_buffer_dict(default_buffer_prototype())["zarr.json"].to_bytes()


def lock_path(store: str | os.PathLike) -> Path:
    """The store's lock file, beside it (inside, Zarr would warn of a file it does not know)."""
    store = Path(store)
    return store.with_name(store.name + ".lock")


@dataclass(frozen=True)
class LogInfo:
    """What the store needs to know about one log, found without keeping its frames (error set if unusable)."""

    path: str
    sha256: str
    seed: int = -1
    n_frames: int = 0
    height: int = 0
    width: int = 0
    config: dict = field(default_factory=dict)
    goal: np.ndarray | None = None
    kind: str = "world"
    error: str | None = None
    world: str = DEFAULT_WORLD

    @property
    def name(self) -> str:
        return Path(self.path).name


def inspect_for_store(path: str | os.PathLike) -> LogInfo:
    """Validate one log and collect its checksum, seed, shape, config and goal track."""
    path = str(path)
    try:
        sha = sha256_file(path)
    except OSError as error:
        return LogInfo(path, "", error=f"{path}: cannot read: {error}")
    try:
        log = read_episode_log(path)
    except LogError as error:
        return LogInfo(path, sha, error=str(error))
    H, W = log.frames.shape[1:]
    config = json.loads(log.metadata["config"])
    return LogInfo(
        path,
        sha,
        log.seed,
        log.n_frames,
        H,
        W,
        config,
        log.goal,
        log.metadata.get("kind", "world"),
        world=log.entry.name,
    )


def load_frames(path: str) -> np.ndarray:
    """(T, H, W) uint8 frames of a log (already validated by `inspect_for_store`)."""
    return read_episode_log(path).frames


def store_problem(store: str | os.PathLike) -> str | None:
    """Why `store` cannot be created or extended as a frames store (None: it can): a file, a folder holding other
    things, or a Zarr store that is not a dynplan frames store."""
    path = Path(store)
    if not path.exists():
        return None
    if not path.is_dir():
        return f"{store}: is a file, not a Zarr store"
    meta = path / "zarr.json"
    if not meta.is_file():
        entries = [p.name for p in path.iterdir()][:3]
        return None if not entries else f"{store}: is a folder but not a Zarr store (it holds {', '.join(entries)}…)"
    try:
        attrs = json.loads(meta.read_text()).get("attributes", {})
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        return f"{store}/zarr.json: not readable JSON ({error})"
    if attrs and attrs.get("format") != STORE_FORMAT:
        return f"{store}: is a Zarr store but not a dynplan frames store (format {attrs.get('format')!r})"
    if attrs and attrs.get("format_version") != STORE_VERSION:
        return (
            f"{store}: is a frames store of format version {attrs.get('format_version')!r}; this dynplan extends "
            f"version {STORE_VERSION} (checksummed chunks): move it aside and build a new one from its logs"
        )
    return None


def list_logs(log_dir: str | os.PathLike) -> list[Path]:
    """The episode logs in a folder, sorted by name; a missing folder is an error that names it."""
    log_dir = Path(log_dir)
    if not log_dir.is_dir():
        raise FileNotFoundError(f"{log_dir}: no such folder of episode logs")
    return sorted(p for p in log_dir.glob("*.mcap") if p.is_file())


def committed(group: zarr.Group) -> int:
    """Episodes committed to the store: the `episodes` attribute, written after each appended batch."""
    return int(group.attrs.get("episodes", 0)) if "log_sha256" in group else 0


def episodes_digest(checksums: Sequence[str]) -> str:
    """A key for a prefix of the store's episodes: the digest of their logs' checksums, in order."""
    return hashlib.sha256("".join(checksums).encode()).hexdigest()


def committed_checksums(store: str | os.PathLike) -> list[str]:
    """SHA-256 of every log committed to `store` (empty if there is no store yet)."""
    if not Path(store, "zarr.json").is_file():
        return []
    group = zarr.open_group(str(store), mode="r", use_consolidated=False)
    n = committed(group)
    return list(read(store, group["log_sha256"], slice(0, n))) if n else []


def fingerprint(store: str | os.PathLike) -> str:
    """A key for the store's contents: its world and config, frame count and the checksums of its logs, in order."""
    group = zarr.open_group(str(store), mode="r", use_consolidated=False)
    parts = [group.attrs.get("config"), group.attrs.get("n_frames"), committed_checksums(store)]
    if "world" in group.attrs:  # the road's stores never named their world
        parts.append(group.attrs["world"])
    return hashlib.sha256(json.dumps(parts, sort_keys=True).encode()).hexdigest()
