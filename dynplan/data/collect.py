"""Record episodes as MCAP logs, one file per seed, resumably.

`record_episode` is idempotent: a log that equals what its seed records (logs are reproducible byte for byte
from seed and config) is left alone, any other log of that world (damaged, or valid but with other content) is
rewritten, and a valid log of a *different* world (another level or grid) is an error rather than replaced.
Writes are atomic, so an interrupted run leaves no partial log under its final name.
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Annotated

from pydantic import Field

from dynplan.arguments import Bounds, checked
from dynplan.config import Config
from dynplan.files import stale_temporaries as stale_files
from dynplan.files import write_bytes_atomic
from dynplan.logs.reader import LogError, read_episode_log
from dynplan.logs.recording import fresh_recording, recording_problem
from dynplan.logs.writer import write_episode_log
from dynplan.world import DEFAULT_WORLD, Recording, world, world_of


class CollectPlan(Config):
    """Which episodes a collection records: seeds seed … seed + episodes − 1."""

    episodes: int = Field(10, ge=1, le=10_000_000, description="number of episodes")
    seed: int = Field(0, ge=0, le=2**62, description="seed of the first episode")

    @property
    def seeds(self) -> list[int]:
        return list(range(self.seed, self.seed + self.episodes))


@dataclass(frozen=True)
class RecordResult:
    """One episode's fate in a collection run: status is "written", "rewritten" or "skipped"."""

    seed: int
    path: str
    status: str

    def to_dict(self) -> dict:
        return asdict(self)


def log_path(out_dir: str | os.PathLike, seed: int) -> Path:
    """Where the log of `seed` lives in a collection folder."""
    return Path(out_dir) / f"episode_{seed:010d}.mcap"


@checked
def record_episode(
    out_dir: str | os.PathLike,
    seed: Annotated[int, Bounds(0, 2**62)],
    config: Config | dict | None = None,
    n_frames: Annotated[int, Bounds(1, 100_001)] | None = None,
    world_name: str = DEFAULT_WORLD,
) -> RecordResult:
    """Make sure `out_dir` holds the log of the episode `seed` of a world under `config` (`n_frames` frames; a
    config of the world `world_name` given as a dict, or its recording default): a log already there is kept
    ("skipped") only if it is what the seed records, and rewritten otherwise."""
    entry, config, n_frames = _recording_of(config, n_frames, world_name)
    path = log_path(out_dir, entry.check_seed(seed))
    episode = entry.record(config, seed, n_frames)
    if not path.exists():
        write_episode_log(path, episode, n_frames=n_frames)
        return RecordResult(seed, str(path), "written")
    fresh = fresh_recording(episode, n_frames, path.name)
    if _is_recording(path, fresh, episode, n_frames):
        return RecordResult(seed, str(path), "skipped")
    write_bytes_atomic(path, fresh)
    return RecordResult(seed, str(path), "rewritten")


def _recording_of(config: Config | dict | None, n_frames: int | None, world_name: str) -> tuple:
    """(the world's entry, its recording config, the frames an episode records) for `record_episode`'s arguments."""
    entry = world_of(config) if isinstance(config, Config) else world(world_name)
    config = config if isinstance(config, Config) else entry.recording if config is None else entry.config(config)
    return entry, config, config.max_steps if n_frames is None else n_frames


def all_recorded(
    out_dir: str | os.PathLike,
    seeds: list[int],
    config: Config | dict | None = None,
    n_frames: int | None = None,
    world_name: str = DEFAULT_WORLD,
) -> bool:
    """Whether `out_dir` already holds the log of every seed of `seeds` as `record_episode` would record it (so a
    collection has nothing to do); False at the first missing or differing log."""
    if not all(log_path(out_dir, seed).is_file() for seed in seeds):
        return False
    entry, config, n_frames = _recording_of(config, n_frames, world_name)
    for seed in seeds:
        path, episode = log_path(out_dir, seed), entry.record(config, entry.check_seed(seed), n_frames)
        if not _is_recording(path, fresh_recording(episode, n_frames, path.name), episode, n_frames):
            return False
    return True


def _is_recording(path: Path, fresh: bytes, world: Recording, n_frames: int) -> bool:
    """Whether the log at `path` is the recording `fresh` of `world` (`dynplan.logs.recording`). A valid log of
    another world is an error: it is not this run's to replace."""
    try:
        log = read_episode_log(path)
    except LogError:
        return False
    config, seed, name = world.config, world.seed, world_of(world.config).name
    recorded = json.loads(log.metadata["config"])
    if (log.entry.name, recorded, log.n_frames, log.seed) != (name, config.model_dump(), n_frames, seed):
        raise LogError(
            path,
            f"already holds seed {log.seed} recorded with {recorded} over {log.n_frames} frames in the "
            f"{log.entry.name} world; this run asks for seed {seed}, {config.model_dump()} over {n_frames} in the "
            f"{name} world — use another output folder",
        )
    return recording_problem(path, log, world, fresh) is None


def stale_temporaries(out_dir: str | os.PathLike) -> list[Path]:
    """Temporary log files that writers no longer running left behind in `out_dir` (safe to delete; another
    collection's live ones are not among them)."""
    return stale_files(out_dir, "episode_*.mcap")
