"""Whether a log is what its seed records. dynplan's recordings are reproducible from their seed and world config
(about 20 ms a road log, a second an Atari game's), so a log that says dynplan recorded it (its `dynplan` record carries
`dynplan_version`) is checked against a fresh recording: equal bytes settle it at once; otherwise its content
(record, frames, goal track, agent start) must be the recording's, since another version of dynplan or of its
compression libraries may encode the same episode in other bytes. A log of one's own world (no `dynplan_version`)
is read for what it is.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from dynplan.logs.reader import EpisodeLog, LogError, read_episode_log
from dynplan.logs.writer import episode_metadata, write_episode_log
from dynplan.world import DEFAULT_WORLD, Recording


def fresh_recording(world: Recording, n_frames: int, name: str = "episode.mcap") -> bytes:
    """The bytes dynplan writes for the log of `world` over `n_frames` frames."""
    with tempfile.TemporaryDirectory(prefix="dynplan-record-") as folder:
        return write_episode_log(Path(folder, name), world, n_frames=n_frames).read_bytes()


def recording_problem(path: str | os.PathLike, log: EpisodeLog, world: Recording, fresh: bytes) -> str | None:
    """How the log at `path` (read as `log`) differs from `fresh`, the recording of `world`; None when it is that
    recording (in its bytes, or in what it records)."""
    if Path(path).read_bytes() == fresh:
        return None
    if log.agent is not None or log.imagined is not None:
        return "it records a planner's episode, not only the world"
    expected = episode_metadata(world, log.n_frames, "world")
    ours = {k: v for k, v in expected.items() if k != "dynplan_version"}
    theirs = {k: v for k, v in log.metadata.items() if k != "dynplan_version"}
    if theirs != ours:
        keys = sorted(k for k in set(ours) | set(theirs) if ours.get(k) != theirs.get(k))
        return f"its record differs from the seed's in {', '.join(keys)}"
    goal = None if world.goal is None else world.goal[: log.n_frames]
    for name, (a, b) in {
        "frames": (log.frames, world.frames[: log.n_frames]),
        "goal track": (log.goal, goal),
        "agent start": (log.agent_start, world.agent_start),
    }.items():
        if not (a is None and b is None) and (a is None or b is None or not np.array_equal(a, b)):
            return f"its {name} differ from the seed's"
    return None


def check_recorded(log: EpisodeLog) -> EpisodeLog:
    """`log`, if it is what its seed records or a log of one's own world; otherwise a LogError naming the file."""
    if "dynplan_version" not in log.metadata or log.metadata.get("kind") != "world":
        return log  # one's own episode, or a replay (which records a planner, not only a seed)
    entry = log.entry
    try:
        world = entry.record(log.config, log.seed, log.n_frames)
    except ValueError as error:
        raise LogError(log.path, f"is no recording of its world: {error}") from None
    problem = recording_problem(log.path, log, world, fresh_recording(world, log.n_frames, log.path.name))
    if problem:
        option = f" --world {entry.name}" if entry.name != DEFAULT_WORLD else ""
        again = f"python -m flows.collect{option} --out {log.path.parent} --seed {log.seed} --episodes 1"
        raise LogError(
            log.path, f"is not what seed {log.seed} records: {problem} (the file is damaged; record it again: {again})"
        )
    return log


def read_recorded_log(path: str | os.PathLike) -> EpisodeLog:
    """`read_episode_log(path)`, checked with `check_recorded`: what a planner replays is what its seed records."""
    return check_recorded(read_episode_log(path))


def read_world_recording(path: str | os.PathLike, world_name: str, wanted: str) -> EpisodeLog:
    """`read_recorded_log(path)`, refused unless it is a recording of world `world_name` as `flows.collect` writes
    it: else a LogError naming what the log is, then `wanted` (the recording the command plays, and how to make one)."""
    recorded = read_recorded_log(path)
    if recorded.entry.name != world_name or recorded.metadata.get("kind") != "world":
        kind = recorded.metadata.get("kind")
        raise LogError(path, f"is a {recorded.entry.name} log of kind {kind!r}; {wanted}")
    return recorded


def of_world(log: EpisodeLog, world_name: str) -> EpisodeLog:
    """`log`, if it records the world `world_name`; else a LogError naming the world it records and the `--world`
    that reads it."""
    found = log.entry.name
    if found != world_name:
        raise LogError(log.path, f"is a {found} log, not one of the {world_name} world; read it with --world {found}")
    return log
