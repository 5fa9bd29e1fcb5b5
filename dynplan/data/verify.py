"""Check every chunk of a frames store and repair damaged episodes from their logs.

`verify_store` reads each chunk of each array up to the committed episode count and reports every chunk that
fails its checksum, does not decode, is missing or holds what the array cannot (a pixel value outside the world's,
a seed outside its range, a goal off the frame: `dynplan.data.contents`), naming the array, the chunk and the
episodes in it. Given the
folder of logs (or their `LogInfo`s), it rewrites each damaged chunk of the frames store from the logs of the
episodes it holds, finding each episode's log by its SHA-256, else its log name, else its seed, and checks the
chunk again. A damaged chunk of a code array (`codes_<name>`) is derived data: its encoding is marked undone
from that episode on, so the next `flows.train` of the prior re-encodes it.

Before any chunk is read, the metadata is checked against the store's format (`dynplan.data.metadata`): every
`zarr.json` must be JSON with the keys Zarr needs, each array must have the format's data type, chunk shape, codecs
(zstd, then CRC-32C), fill value and dimensions, and the group's attributes must agree with each other and with
the arrays' lengths. An array whose metadata is damaged is never read or written through that metadata: given the
logs, its metadata is rewritten as the format's and its chunks from the logs; otherwise it is reported, with how to
repair or rebuild the store.
"""

from __future__ import annotations

import os
import shutil
import warnings
from collections.abc import Callable, Sequence
from contextlib import nullcontext
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import zarr

from dynplan.config import ConfigError
from dynplan.data.chunks import Chunk, chunk_file, chunk_problem, chunks, is_checksummed, writable
from dynplan.data.contents import Check, store_checks
from dynplan.data.metadata import REBUILD, REENCODE, StoreMetadata, check_metadata
from dynplan.data.store import (
    LogInfo,
    episodes_digest,
    format_metadata,
    inspect_for_store,
    list_logs,
    load_frames,
    lock_path,
    sha256_file,
    store_world,
)
from dynplan.files import exclusive, write_bytes_atomic
from dynplan.progress import progress
from dynplan.world import world


@dataclass
class Damage:
    """A chunk that could not be read, what was wrong, and whether it was repaired (or why not)."""

    array: str
    chunk: str
    rows: range
    problem: str
    episodes: str
    repaired: bool = False
    unrepaired_because: str | None = None
    action: str = "repaired"
    #: "chunk", or damage to metadata: "array metadata" (`chunk` names its zarr.json), "group attributes" or
    #: "consolidated metadata" (`array` is "" for the group's own).
    kind: str = "chunk"
    #: Group attributes the format determines, with their values (what repairing them sets).
    fix: dict | None = None

    def describe(self) -> str:
        state = self.action if self.repaired else f"not repaired: {self.unrepaired_because or 'no logs given'}"
        if self.kind == "chunk":
            return f"array {self.array!r}, chunk {self.chunk} ({self.episodes}): {self.problem}; {state}"
        where = f"array {self.array!r}" if self.array else "the group"
        return f"{where}, {self.kind} {self.chunk} ({self.episodes}): {self.problem}; {state}"


@dataclass
class VerifyReport:
    """What `verify_store` checked and found."""

    store: str
    episodes: int
    chunks: int = 0
    damage: list[Damage] = field(default_factory=list)

    @property
    def unrepaired(self) -> list[Damage]:
        return [d for d in self.damage if not d.repaired]

    def to_dict(self) -> dict:
        return {
            "store": self.store,
            "episodes": self.episodes,
            "chunks": self.chunks,
            "damage": [d.describe() for d in self.damage],
            "unrepaired": len(self.unrepaired),
        }


def _column(array: zarr.Array, n: int, bad: set[str]) -> list:
    """The first `n` values of a 1-D array, None where its chunk is damaged."""
    values: list = [None] * n
    for chunk in chunks(array, n):
        if chunk.key not in bad:
            values[chunk.rows.start : chunk.rows.stop] = list(array[chunk.region])
    return values


Logs = str | os.PathLike | Sequence[str | os.PathLike | LogInfo]


def verify_store(
    store: str | os.PathLike, logs: Logs | None = None, repair: bool = True, lock: bool = True
) -> VerifyReport:
    """Check the metadata of `store` against its format and read every chunk, reporting what is damaged; with
    `logs` (a folder of logs, their paths or their `LogInfo`s) and `repair`, rewrite the damaged episodes (and
    damaged array metadata) from them. Holds the store's lock unless the caller does (`lock=False`)."""
    store = str(store)
    if not Path(store, "zarr.json").is_file():
        raise FileNotFoundError(f"{store}: no frames store there (no zarr.json)")
    guard = exclusive(lock_path(store), waiting=f"{store}: another build or repair holds the store")
    with guard if lock else nullcontext():
        meta = check_metadata(store)
        n = meta.episodes or 0
        report = VerifyReport(store, n)
        report.damage = [Damage(rows=range(0, n), episodes="every episode", **p) for p in meta.problems]
        if not n:  # nothing committed (or the count itself is damaged: reported)
            return report
        group = zarr.open_group(store, mode="r+" if repair else "r", use_consolidated=False)
        names = [name for name in meta.shapes if name not in meta.damaged]
        report.damage.extend(_short_arrays(meta, n))
        checks = _content_checks(dict(group.attrs), _seeds(store, group, n) if "seed" in names else None)
        found = _check_chunks(store, group, names, n, report, checks)
        bad = {name: {c.key for c, _ in found[name]} for name in names}
        identity = {
            name: _column(group[name], n, bad[name])
            for name in ("seed", "log_name", "log_sha256")
            if name in names and meta.shapes[name][0] >= n
        }
        describe = _describer(identity, n)
        report.damage.extend(Damage(name, c.key, c.rows, p, describe(c.rows)) for name in names for c, p in found[name])
        if repair and report.damage:
            repairer = _Repair(store, group, n, identity, logs, meta, checks)
            for item in report.damage:
                repairer.repair(item)
            repairer.consolidate(report.damage)
        return report


def _content_checks(attributes: dict, seeds: list | None) -> dict[str, Check]:
    """What each array may hold (`store_checks`, the frames against their `seeds` too); none where the store's world
    is not one of dynplan's (the metadata's check reports that)."""
    try:
        return store_checks(world(store_world(attributes)), attributes, seeds)
    except ConfigError:
        return {}


def _seeds(store: str, group: zarr.Group, n: int) -> list:
    """The first `n` seeds, None where their chunk cannot be read (its own check reports it)."""
    array = group["seed"]
    return _column(array, n, {c.key for c in chunks(array, n) if chunk_problem(store, array, c) is not None})


def _short_arrays(meta: StoreMetadata, n: int) -> list[Damage]:
    """Arrays that are missing, or hold fewer than the `n` committed episodes (unless the group's count is the
    damaged one: `check_metadata` reports that)."""
    if any("'episodes' is" in p["problem"] for p in meta.problems):
        return []
    damage = []
    for name in meta.arrays:
        if name in meta.damaged:
            continue
        if name not in meta.shapes:
            damage.append(Damage(name, "-", range(0, n), "the array is missing", "every episode"))
        elif meta.shapes[name][0] < n:
            length = meta.shapes[name][0]
            damage.append(
                Damage(
                    name,
                    "-",
                    range(length, n),
                    f"holds {length} of the {n} committed episodes",
                    "the episodes after those",
                )
            )
    return damage


def _check_chunks(
    store: str, group: zarr.Group, names: list[str], n: int, report: VerifyReport, checks: dict[str, Check]
) -> dict:
    """Read every chunk of the arrays `names` up to their committed rows, checking what each holds where `checks`
    says what it may: {array: [(chunk, problem)]}."""
    found: dict[str, list[tuple[Chunk, str]]] = {}
    for name in progress(names, total=len(names), description="verify"):
        array = group[name]
        rows = int(array.attrs.get("episodes", n)) if name.startswith("codes_") else n
        if not is_checksummed(array):
            problem = "its chunks carry no checksum, so damage cannot be detected"
            report.damage.append(Damage(name, "-", range(0, 0), problem, "every episode"))
        found[name] = []
        for chunk in chunks(array, rows):
            report.chunks += 1
            problem = chunk_problem(store, array, chunk, checks.get(name))
            if problem:
                found[name].append((chunk, problem))
    return found


def _describer(identity: dict[str, list], n: int) -> Callable[[range], str]:
    """describe(rows): the episodes of `rows` with their seeds and logs, as far as the store still knows them."""

    def describe(rows: range) -> str:
        shown = []
        for row in list(rows)[:3]:
            seed, log = (identity.get(k, [None] * n)[row] for k in ("seed", "log_name"))
            shown.append(
                f"episode {row}"
                + (f", seed {seed}" if seed is not None else "")
                + (f", log {log}" if log is not None else "")
            )
        more = f" and {len(rows) - 3} more" if len(rows) > 3 else ""
        return "; ".join(shown) + more

    return describe


class _Repair:
    """Rewrites damaged chunks from the logs of the episodes they hold."""

    def __init__(
        self,
        store: str,
        group: zarr.Group,
        n: int,
        identity: dict[str, list],
        logs,
        meta: StoreMetadata,
        checks: dict[str, Check],
    ) -> None:
        self.store, self.group, self.n, self.identity, self.meta = store, group, n, identity, meta
        self.checks = checks
        if logs is None:
            self.logs: list[LogInfo | Path] = []
        elif isinstance(logs, (str, os.PathLike)):
            self.logs = list(list_logs(logs))
        else:
            self.logs = [log if isinstance(log, LogInfo) else Path(log) for log in logs]
        self._by_sha: dict[str, str] | None = None
        self._infos: dict[str, LogInfo] = {}

    def _sha_index(self) -> dict[str, str]:
        if self._by_sha is None:
            self._by_sha = {}
            for log in self.logs:
                if isinstance(log, LogInfo):
                    if not log.error:
                        self._by_sha[log.sha256] = log.path
                else:
                    self._by_sha[sha256_file(log)] = str(log)
        return self._by_sha

    def _info(self, path: str) -> LogInfo:
        if path not in self._infos:
            self._infos[path] = inspect_for_store(path)
        return self._infos[path]

    def _log_of(self, row: int) -> LogInfo | str:
        """The log of episode `row`, or why it was not found."""
        sha, name, seed = (self.identity.get(k, [None] * self.n)[row] for k in ("log_sha256", "log_name", "seed"))
        candidates = []
        if sha is not None:
            candidates = [self._sha_index()[sha]] if sha in self._sha_index() else []
        elif name is not None:
            candidates = [str(p) for p in self._paths() if Path(p).name == name]
        elif seed is not None:
            candidates = [p for p in map(str, self._paths()) if self._info(p).seed == int(seed)]
        else:
            return f"episode {row} has lost its seed, log name and checksum; rebuild the store from its logs"
        for path in candidates:
            info = self._info(path)
            if not info.error and (sha is None or info.sha256 == sha):
                return info
        wanted = f"SHA-256 {sha}" if sha else f"name {name}" if name else f"seed {seed}"
        return f"no log with {wanted} (episode {row}) among the logs given"

    def _paths(self) -> list[str]:
        return [log.path if isinstance(log, LogInfo) else str(log) for log in self.logs]

    def repair(self, item: Damage) -> None:
        if item.kind != "chunk":
            self._repair_metadata(item)
            return
        if item.chunk == "-":
            item.unrepaired_because = f"only damaged chunks can be repaired in place; {REBUILD}"
            return
        array = self.group[item.array]
        if not self.logs and not item.array.startswith("codes_"):
            return
        if item.array.startswith("codes_"):
            self._reset_codes(array, item.rows.start)
            item.repaired = True
            item.action = (
                f"its encoding is marked undone from episode {item.rows.start} on; the next "
                "`python -m flows.train vqvae` of its model encodes it again"
            )
            return
        item.unrepaired_because = self._rewrite(array, item.chunk, item.rows)
        item.repaired = item.unrepaired_because is None

    def _rewrite(self, array: zarr.Array, key: str, rows: range) -> str | None:
        """Rewrite the chunk `key` of `array` (rows `rows`) from the logs of its episodes; why not, if not."""
        rows = range(rows.start, min(rows.stop, self.n))
        infos = []
        for row in rows:
            info = self._log_of(row)
            if isinstance(info, str):
                return info
            infos.append(info)
        values = {
            "frames": lambda: np.stack([load_frames(i.path) for i in infos]),
            "goal": lambda: np.stack([i.goal for i in infos]),
            "seed": lambda: np.array([i.seed for i in infos], dtype=np.int64),
            "log_name": lambda: np.array([i.name for i in infos]),
            "log_sha256": lambda: np.array([i.sha256 for i in infos]),
        }[array.basename]()
        chunk_file(self.store, array, key).unlink(missing_ok=True)  # a damaged chunk cannot be updated
        region = (slice(rows.start, rows.stop), *(slice(None),) * (array.ndim - 1))
        writable(array)[region] = values
        chunk = next(c for c in chunks(array) if c.key == key)
        return chunk_problem(self.store, array, chunk, self.checks.get(array.basename))

    def _repair_metadata(self, item: Damage) -> None:
        """Group attributes the format determines are set; a code array is removed (derived data, encoded again);
        an array of episodes gets the format's metadata and, from the logs, every chunk."""
        if item.kind == "group attributes" and item.fix:
            self.group.attrs.update(item.fix)
            item.repaired, item.action = True, "set to the format's"
        elif item.kind == "array metadata" and item.array.startswith("codes_"):
            shutil.rmtree(Path(self.store, item.array))
            item.repaired, item.action = True, f"the array is removed; {REENCODE.split('; ')[1]}"
        elif item.kind == "array metadata" and self.meta.geometry and self.logs:
            path = Path(self.store, item.array)
            attributes = self.meta.attributes.get(item.array)
            write_bytes_atomic(path / "zarr.json", format_metadata(item.array, self.n, self.meta.geometry, attributes))
            shutil.rmtree(path / "c", ignore_errors=True)  # written under other metadata: none can be trusted
            array = self.group[item.array]
            for chunk in chunks(array, self.n):
                item.unrepaired_because = self._rewrite(array, chunk.key, chunk.rows)
                if item.unrepaired_because:
                    return
            item.repaired, item.action = True, "its metadata is rewritten as the format's and its chunks from the logs"

    def consolidate(self, damage: list[Damage]) -> None:
        """Consolidate the metadata again after a repair of metadata, unless an array's own is still damaged (the
        consolidated copies would take its damage)."""
        touched = any(d.kind != "chunk" and d.repaired for d in damage)
        if self.meta.consolidated is None or not (touched or any(d.kind == "consolidated metadata" for d in damage)):
            return
        if any(d.kind == "array metadata" and not d.repaired for d in damage):
            for item in damage:
                if item.kind == "consolidated metadata":
                    item.unrepaired_because = "the arrays' own metadata is damaged too"
            return
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="Consolidated metadata is currently not part")
            zarr.consolidate_metadata(self.store)
        for item in damage:
            if item.kind == "consolidated metadata":
                item.repaired, item.action = True, "consolidated again from the arrays' own metadata"

    def _reset_codes(self, array: zarr.Array, first_bad: int) -> None:
        """Mark the encoding undone from `first_bad` on, so that the next encoding redoes it from there."""
        done = min(int(array.attrs.get("episodes", 0)), first_bad)
        checksums = self.identity.get("log_sha256", [])
        if None in checksums[:done]:
            done = 0
        array.attrs.update(episodes=done, source_digest=episodes_digest([str(c) for c in checksums[:done]]))
