"""Check every chunk of a frames store and repair damaged episodes from their logs.

`verify_store` reads each chunk of each array up to the committed episode count and reports every chunk that
fails its checksum, does not decode or is missing, naming the array, the chunk and the episodes in it. Given the
folder of logs (or their `LogInfo`s), it rewrites each damaged chunk of the frames store from the logs of the
episodes it holds, finding each episode's log by its SHA-256, else its log name, else its seed, and checks the
chunk again. A damaged chunk of a code array (`codes_<name>`) is derived data: its encoding is marked undone
from that episode on, so the next `flows.train` of the prior re-encodes it.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from contextlib import nullcontext
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import zarr

from dynplan.data.chunks import Chunk, chunk_file, chunk_problem, chunks, is_checksummed
from dynplan.data.store import (
    ARRAYS,
    LogInfo,
    committed,
    episodes_digest,
    inspect_for_store,
    list_logs,
    load_frames,
    lock_path,
    sha256_file,
)
from dynplan.files import exclusive
from dynplan.progress import progress


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

    def describe(self) -> str:
        state = self.action if self.repaired else f"not repaired: {self.unrepaired_because or 'no logs given'}"
        return f"array {self.array!r}, chunk {self.chunk} ({self.episodes}): {self.problem}; {state}"


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
        return {"store": self.store, "episodes": self.episodes, "chunks": self.chunks,
                "damage": [d.describe() for d in self.damage], "unrepaired": len(self.unrepaired)}  # fmt: skip


def _code_arrays(group: zarr.Group) -> list[str]:
    return sorted(name for name in group.array_keys() if name.startswith("codes_"))


def _column(array: zarr.Array, n: int, bad: set[str]) -> list:
    """The first `n` values of a 1-D array, None where its chunk is damaged."""
    values: list = [None] * n
    for chunk in chunks(array, n):
        if chunk.key not in bad:
            values[chunk.rows.start : chunk.rows.stop] = list(array[chunk.region])
    return values


Logs = str | os.PathLike | Sequence[str | os.PathLike | LogInfo]


def verify_store(store: str | os.PathLike, logs: Logs | None = None, repair: bool = True,
                 lock: bool = True) -> VerifyReport:  # fmt: skip
    """Read every chunk of `store` and report the damaged ones; with `logs` (a folder of logs, their paths or
    their `LogInfo`s) and `repair`, rewrite the damaged episodes from them. Holds the store's lock unless the
    caller does (`lock=False`)."""
    store = str(store)
    if not Path(store, "zarr.json").is_file():
        raise FileNotFoundError(f"{store}: no frames store there (no zarr.json)")
    guard = exclusive(lock_path(store), waiting=f"{store}: another build or repair holds the store")
    with guard if lock else nullcontext():
        group = zarr.open_group(store, mode="r+" if repair else "r", use_consolidated=False)
        n = committed(group)
        report = VerifyReport(store, n)
        if n == 0:
            return report
        found: dict[str, list[tuple[Chunk, str]]] = {}
        names = [name for name in ARRAYS if name in group] + _code_arrays(group)
        for name in ARRAYS:
            if name not in group:
                report.damage.append(Damage(name, "-", range(0, n), "the array is missing", "every episode"))
            elif group[name].shape[0] < n:
                report.damage.append(Damage(name, "-", range(group[name].shape[0], n),
                                            f"holds {group[name].shape[0]} of the {n} committed episodes",
                                            "the episodes after those"))  # fmt: skip
        for name in progress(names, total=len(names), description="verify"):
            array = group[name]
            rows = int(array.attrs.get("episodes", n)) if name.startswith("codes_") else n
            if not is_checksummed(array):
                problem = "its chunks carry no checksum, so damage cannot be detected"
                report.damage.append(Damage(name, "-", range(0, 0), problem, "every episode"))
            found[name] = []
            for chunk in chunks(array, rows):
                report.chunks += 1
                problem = chunk_problem(store, array, chunk)
                if problem:
                    found[name].append((chunk, problem))
        bad = {name: {c.key for c, _ in found[name]} for name in names}
        identity = {name: _column(group[name], n, bad[name]) for name in ("seed", "log_name", "log_sha256")
                    if name in group and group[name].shape[0] >= n}  # fmt: skip

        def describe(rows: range) -> str:
            shown = []
            for row in list(rows)[:3]:
                seed, log = (identity.get(k, [None] * n)[row] for k in ("seed", "log_name"))
                shown.append(f"episode {row}" + (f", seed {seed}" if seed is not None else "")
                             + (f", log {log}" if log is not None else ""))  # fmt: skip
            more = f" and {len(rows) - 3} more" if len(rows) > 3 else ""
            return "; ".join(shown) + more

        damage = [Damage(name, c.key, c.rows, p, describe(c.rows)) for name in names for c, p in found[name]]
        report.damage.extend(damage)
        if repair and damage:
            repairer = _Repair(store, group, n, identity, logs)
            for item in damage:
                repairer.repair(item)
        return report


class _Repair:
    """Rewrites damaged chunks from the logs of the episodes they hold."""

    def __init__(self, store: str, group: zarr.Group, n: int, identity: dict[str, list], logs) -> None:
        self.store, self.group, self.n, self.identity = store, group, n, identity
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
        if item.chunk == "-":
            item.unrepaired_because = "only damaged chunks can be repaired in place; rebuild the store from its logs"
            return
        array = self.group[item.array]
        if not self.logs and not item.array.startswith("codes_"):
            return
        if item.array.startswith("codes_"):
            self._reset_codes(array, item.rows.start)
            item.repaired = True
            item.action = (f"its encoding is marked undone from episode {item.rows.start} on; the next "
                           "`python -m flows.train vqvae` of its model encodes it again")  # fmt: skip
            return
        rows = range(item.rows.start, min(item.rows.stop, self.n))
        infos = []
        for row in rows:
            info = self._log_of(row)
            if isinstance(info, str):
                item.unrepaired_because = info
                return
            infos.append(info)
        values = {
            "frames": lambda: np.stack([load_frames(i.path) for i in infos]),
            "goal": lambda: np.stack([i.goal for i in infos]),
            "seed": lambda: np.array([i.seed for i in infos], dtype=np.int64),
            "log_name": lambda: np.array([i.name for i in infos]),
            "log_sha256": lambda: np.array([i.sha256 for i in infos]),
        }[item.array]()
        chunk_file(self.store, array, item.chunk).unlink(missing_ok=True)  # a damaged chunk cannot be updated
        region = (slice(rows.start, rows.stop), *(slice(None),) * (array.ndim - 1))
        array[region] = values
        problem = chunk_problem(self.store, array, next(c for c in chunks(array) if c.key == item.chunk))
        item.repaired = problem is None
        item.unrepaired_because = problem

    def _reset_codes(self, array: zarr.Array, first_bad: int) -> None:
        """Mark the encoding undone from `first_bad` on, so that the next encoding redoes it from there."""
        done = min(int(array.attrs.get("episodes", 0)), first_bad)
        checksums = self.identity.get("log_sha256", [])
        if None in checksums[:done]:
            done = 0
        array.attrs.update(episodes=done, source_digest=episodes_digest([str(c) for c in checksums[:done]]))
