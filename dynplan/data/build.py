"""Building the frames store (`dynplan.data.store`'s layout) from logs: new logs appended with dask, the episodes
already in checked first and repaired from these logs if damaged (`dynplan.data.verify`), under the store's lock.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import dask
import dask.array as da
import numpy as np
import zarr

from dynplan.data.chunks import COMPRESSORS, commit_rows, staged, write_rows
from dynplan.data.store import (
    BATCH_EPISODES,
    STORE_FORMAT,
    STORE_VERSION,
    Y_AXIS,
    LogInfo,
    array_specs,
    committed,
    committed_checksums,
    inspect_for_store,
    load_frames,
    lock_path,
    store_arrays,
    store_problem,
    store_world,
)
from dynplan.data.verify import verify_store
from dynplan.files import exclusive
from dynplan.version import __version__
from dynplan.world import DEFAULT_WORLD, world


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
        return {
            "store": self.store,
            "episodes": self.episodes,
            "added": self.added,
            "skipped": self.skipped,
            "failed": self.failed,
            "repaired": self.repaired,
        }


def _geometry(info: LogInfo) -> dict:
    return {
        "world": info.world,
        "config": info.config,
        "n_frames": info.n_frames,
        "height": info.height,
        "width": info.width,
    }


def _create(group: zarr.Group, first: LogInfo) -> None:
    T, H, W = first.n_frames, first.height, first.width
    entry = world(first.world)
    geometry = {k: v for k, v in _geometry(first).items() if k != "world" or v != DEFAULT_WORLD}
    group.attrs.update(
        episodes=0,
        format=STORE_FORMAT,
        format_version=STORE_VERSION,
        dynplan_version=__version__,
        **geometry,
        pixel_values=entry.pixel_values(entry.config(first.config)),
        y_axis=Y_AXIS,
    )
    # overwrite=True: a first build killed half-way through creating these is simply started again.
    specs = array_specs(T, H, W)
    for name in store_arrays(entry.name):
        group.create_array(name, compressors=COMPRESSORS, overwrite=True, **specs[name])


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
    report = BuildReport(store, episodes=0)
    if Path(store, "zarr.json").is_file():  # check what is in before relying on it, repairing from these logs
        checked = verify_store(store, [info for info in infos if not info.error], lock=False)
        report.repaired = [d.describe() for d in checked.damage if d.repaired]
        report.failed.update(
            {
                f"{store}/{d.chunk}" if d.kind != "chunk" else f"{store}/{d.array}/{d.chunk}": d.describe()
                for d in checked.unrepaired
            }
        )
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
    _append(group, _acceptable(group, pending, report), report)
    _consolidate(store)
    return report


def _acceptable(group: zarr.Group, pending: Sequence[LogInfo], report: BuildReport) -> list[LogInfo]:
    """The new logs that fit the store (recorded worlds of its geometry, of seeds not in it); the others are
    entered in `report.failed` with the reason."""
    n = committed(group)
    expected = {
        "world": store_world(group.attrs),
        **{k: group.attrs[k] for k in ("config", "n_frames", "height", "width")},
    }
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
    return accepted


def _append(group: zarr.Group, accepted: Sequence[LogInfo], report: BuildReport) -> None:
    """Append `accepted` in batches of `BATCH_EPISODES`, each committed by the group attribute `episodes`, after
    rolling back an interrupted append."""
    n, names = committed(group), store_arrays(store_world(group.attrs))
    for name in names:  # roll back an interrupted append
        commit_rows(group[name], n)
    T, H, W = group.attrs["n_frames"], group.attrs["height"], group.attrs["width"]
    for start in range(0, len(accepted), BATCH_EPISODES):
        batch = accepted[start : start + BATCH_EPISODES]
        k = len(batch)
        frames = da.stack([da.from_delayed(dask.delayed(load_frames)(i.path), (T, H, W), np.uint8) for i in batch])
        da.store(frames, staged(group["frames"], n + k), regions=(slice(n, n + k),), lock=False)
        if "goal" in names:
            write_rows(group["goal"], n, np.stack([i.goal for i in batch]))
        write_rows(group["seed"], n, np.array([i.seed for i in batch], dtype=np.int64))
        write_rows(group["log_name"], n, np.array([i.name for i in batch]))
        write_rows(group["log_sha256"], n, np.array([i.sha256 for i in batch]))
        for name in names:  # every row up to n + k is written: show it
            commit_rows(group[name], n + k)
        n += k
        group.attrs["episodes"] = n  # the commit: everything up to n is complete
        report.added.extend(i.path for i in batch)
    report.episodes = n


def _consolidate(store: str) -> None:
    """Consolidate metadata so that xarray opens the store in one read (zarr-python supports it for v3)."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Consolidated metadata is currently not part")
        zarr.consolidate_metadata(store)


def build_frame_store_from_logs(store: str | os.PathLike, logs: Sequence[str | os.PathLike]) -> BuildReport:
    """Inspect `logs` in parallel with dask, then append the new ones to `store`."""
    infos = dask.compute(*[dask.delayed(inspect_for_store)(str(p)) for p in logs])
    return build_frame_store(store, infos)
