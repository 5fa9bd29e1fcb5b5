"""The frames store: recorded episodes as a chunked Zarr v3 group, built from logs with dask.

Layout (readable with `zarr`, `dask.array.from_zarr` or `xarray.open_zarr`, no dynplan needed):

| array      | shape                        | dtype   | chunks         | dimension_names              |
| ---------- | ---------------------------- | ------- | -------------- | ---------------------------- |
| frames     | (episode, time, y, x)        | uint8   | one episode    | episode, time, y, x          |
| goal       | (episode, time, 2)           | float64 | 64 episodes    | episode, time, yx            |
| seed       | (episode,)                   | int64   | 1024           | episode                      |
| log_name   | (episode,)                   | string  | 1024           | episode                      |
| log_sha256 | (episode,)                   | string  | 1024           | episode                      |

Group attributes hold the format, the world config, n_frames, height, width and the pixel-value legend.
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
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import dask
import dask.array as da
import numpy as np
import zarr

from dynplan.data.chunks import COMPRESSORS, commit_rows, read, staged, write_rows
from dynplan.env.config import FREE, GOAL_VALUE, obstacle_classes
from dynplan.files import exclusive
from dynplan.logs.reader import LogError, read_episode_log

STORE_FORMAT = "dynplan.frames"
#: 2: checksummed chunks; 1 (without checksums) is read but no longer extended.
STORE_VERSION = "2"
#: Episodes appended per dask computation (bounds memory: 64 × 407 × 48 × 48 B ≈ 60 MB).
BATCH_EPISODES = 64

ARRAYS = ("frames", "goal", "seed", "log_name", "log_sha256")


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

    @property
    def name(self) -> str:
        return Path(self.path).name


@dataclass
class BuildReport:
    """Outcome of a build: logs appended, skipped (already in the store) and failed (path → reason)."""

    store: str
    episodes: int
    added: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    failed: dict[str, str] = field(default_factory=dict)
    repaired: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        return {"store": self.store, "episodes": self.episodes, "added": self.added, "skipped": self.skipped,
                "failed": self.failed, "repaired": self.repaired}  # fmt: skip


def sha256_file(path: str | os.PathLike) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as stream:
        for block in iter(lambda: stream.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


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
    return LogInfo(path, sha, log.seed, log.n_frames, H, W, config, log.goal, log.metadata.get("kind", "world"))


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


def _geometry(info: LogInfo) -> dict:
    return {"config": info.config, "n_frames": info.n_frames, "height": info.height, "width": info.width}


def _create(group: zarr.Group, first: LogInfo) -> None:
    T, H, W = first.n_frames, first.height, first.width
    from dynplan.version import __version__

    group.attrs.update(
        episodes=0,
        format=STORE_FORMAT, format_version=STORE_VERSION, dynplan_version=__version__, **_geometry(first),
        pixel_values={"free": FREE, "goal": GOAL_VALUE, **{c.name: c.value for c in obstacle_classes(W)}},
        y_axis="row 0 is the bottom of the world",
    )  # fmt: skip
    # overwrite=True: a first build killed half-way through creating these is simply started again.
    options = {"compressors": COMPRESSORS, "overwrite": True}
    group.create_array("frames", shape=(0, T, H, W), chunks=(1, T, H, W), dtype="uint8",
                       dimension_names=("episode", "time", "y", "x"), **options)  # fmt: skip
    group.create_array("goal", shape=(0, T, 2), chunks=(BATCH_EPISODES, T, 2), dtype="float64",
                       dimension_names=("episode", "time", "yx"), **options)  # fmt: skip
    for name, dtype in (("seed", "int64"), ("log_name", str), ("log_sha256", str)):
        group.create_array(name, shape=(0,), chunks=(1024,), dtype=dtype, dimension_names=("episode",), **options)


def committed(group: zarr.Group) -> int:
    """Episodes committed to the store: the `episodes` attribute, written after each appended batch."""
    return int(group.attrs.get("episodes", 0)) if "log_sha256" in group else 0


def committed_rows(store: str | os.PathLike) -> int:
    """Episodes committed to the store at `store` (0 if there is none yet)."""
    if not Path(store, "zarr.json").is_file():
        return 0
    return committed(zarr.open_group(str(store), mode="r", use_consolidated=False))


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
    """A key for the store's contents: its config, frame count and the checksums of its logs, in order."""
    group = zarr.open_group(str(store), mode="r", use_consolidated=False)
    parts = [group.attrs.get("config"), group.attrs.get("n_frames"), committed_checksums(store)]
    return hashlib.sha256(json.dumps(parts, sort_keys=True).encode()).hexdigest()


def build_frame_store(store: str | os.PathLike, infos: Sequence[LogInfo]) -> BuildReport:
    """Append the logs described by `infos` (from `inspect_for_store`) to the Zarr group at `store`, under the
    store's lock; the episodes of logs already in are checked and, if damaged, repaired from those logs.

    Frames are copied with dask, one task per episode chunk, on whatever dask scheduler is active (a
    `distributed.Client` if one is, threads otherwise). Writes nothing when every log is already in, intact.
    """
    store = str(store)
    problem = store_problem(store)
    if problem:
        raise ValueError(problem)
    with exclusive(lock_path(store), waiting=f"{store}: another build or repair holds the store"):
        return _build_locked(store, infos)


def _build_locked(store: str, infos: Sequence[LogInfo]) -> BuildReport:
    from dynplan.data.verify import verify_store  # verify builds on this module

    report = BuildReport(store, episodes=0)
    if committed_rows(store):  # check what is in before relying on it, repairing from these logs
        checked = verify_store(store, [info for info in infos if not info.error], lock=False)
        report.repaired = [d.describe() for d in checked.damage if d.repaired]
        report.failed.update({f"{store}/{d.array}/{d.chunk}": d.describe() for d in checked.unrepaired})
        if checked.unrepaired:
            return report
    known = set(committed_checksums(store))
    report.episodes = len(known)
    new: dict[str, LogInfo] = {}
    for info in infos:
        if info.error:
            report.failed[info.path] = info.error
        elif info.sha256 in known or info.sha256 in new:
            report.skipped.append(info.path)
        else:
            new[info.sha256] = info
    if not new:
        return report

    # Consolidated metadata may be stale after an interrupted append: write against the arrays' own metadata.
    group = zarr.open_group(store, mode="a", zarr_format=3, use_consolidated=False)
    pending = sorted(new.values(), key=lambda i: (i.seed, i.name))
    if committed(group) == 0:
        _create(group, pending[0])
    n = committed(group)
    expected = {k: group.attrs[k] for k in ("config", "n_frames", "height", "width")}
    seeds = {int(seed): str(name) for seed, name in zip(group["seed"][:n], group["log_name"][:n], strict=True)}
    accepted = []
    for info in pending:
        if info.kind != "world":
            report.failed[info.path] = f"{info.path}: a log of kind {info.kind!r} (a replay), not a recorded world"
        elif _geometry(info) != expected:
            report.failed[info.path] = (
                f"{info.path}: recorded as {_geometry(info)}, but the store holds {expected}; use another store"
            )
        elif info.seed in seeds:
            report.failed[info.path] = f"{info.path}: seed {info.seed} is already in the store ({seeds[info.seed]})"
        else:
            seeds[info.seed] = info.name
            accepted.append(info)

    for name in ARRAYS:  # roll back an interrupted append
        commit_rows(group[name], n)
    T, H, W = expected["n_frames"], expected["height"], expected["width"]
    for start in range(0, len(accepted), BATCH_EPISODES):
        batch = accepted[start : start + BATCH_EPISODES]
        k = len(batch)
        frames = da.stack([da.from_delayed(dask.delayed(load_frames)(i.path), (T, H, W), np.uint8) for i in batch])
        da.store(frames, staged(group["frames"], n + k), regions=(slice(n, n + k),), lock=False)
        write_rows(group["goal"], n, np.stack([i.goal for i in batch]))
        write_rows(group["seed"], n, np.array([i.seed for i in batch], dtype=np.int64))
        write_rows(group["log_name"], n, np.array([i.name for i in batch]))
        write_rows(group["log_sha256"], n, np.array([i.sha256 for i in batch]))
        for name in ARRAYS:  # every row up to n + k is written: show it
            commit_rows(group[name], n + k)
        n += k
        group.attrs["episodes"] = n  # the commit: everything up to n is complete
        report.added.extend(i.path for i in batch)
    report.episodes = n
    _consolidate(store)
    return report


def _consolidate(store: str) -> None:
    """Consolidate metadata so that xarray opens the store in one read (zarr-python supports it for v3)."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Consolidated metadata is currently not part")
        zarr.consolidate_metadata(store)


def build_frame_store_from_logs(store: str | os.PathLike, logs: Sequence[str | os.PathLike]) -> BuildReport:
    """Inspect `logs` in parallel with dask, then append the new ones to `store`."""
    infos = dask.compute(*[dask.delayed(inspect_for_store)(str(p)) for p in logs])
    return build_frame_store(store, infos)
