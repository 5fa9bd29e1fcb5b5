"""Read and validate episode logs.

One pass over the file's records (CRCs checked) collects whatever is intact; then the log is judged. A log
that is missing, empty, not MCAP, truncated, corrupt, or of the wrong kind raises `LogError` naming the file
and the problem — and the message lists what is intact, which `inspect_log` also returns without raising.
Messages are decoded with the schemas embedded in the file, so a log describes itself.
"""

from __future__ import annotations

import json
import os
import struct
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from mcap.exceptions import EndOfFile, McapError
from mcap.records import Channel, DataEnd, Footer, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap_protobuf.decoder import DecoderFactory

from dynplan.cli import InputError
from dynplan.config import Config, ConfigError
from dynplan.logs.format import (
    EPOCH_NS,
    FORMAT,
    FORMAT_VERSION,
    FRAME_PERIOD_NS,
    MCAP_MAGIC,
    METADATA_NAME,
    SCHEMA_FRAME,
    SCHEMA_POSE,
    TOPIC_AGENT_POSE,
    TOPIC_AGENT_STEP,
    TOPIC_FRAME,
    TOPIC_GOAL,
    TOPIC_IMAGINED,
    AgentTrack,
)
from dynplan.world import DEFAULT_WORLD, Recording, World, world


class LogError(InputError):
    """An episode log cannot be used; the message starts with the file's path and says why."""

    def __init__(self, path: str | os.PathLike, problem: str):
        self.path = Path(path)
        self.problem = problem
        super().__init__(f"{path}: {problem}")


@dataclass
class LogListing:
    """What is intact in a log file: topics with their schema and message count, metadata, completeness."""

    path: Path
    size: int
    complete: bool
    problem: str | None
    topics: dict[str, tuple[str, int]] = field(default_factory=dict)  # topic → (schema name, messages)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)

    def describe(self) -> str:
        if not self.topics and not self.metadata:
            return "nothing intact"
        parts = [f"{topic} ({schema}) × {n}" for topic, (schema, n) in self.topics.items()]
        parts += [f"metadata '{name}'" for name in self.metadata]
        return "intact: " + ", ".join(parts)


@dataclass
class _Scan:
    listing: LogListing
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    messages: dict[str, list[Message]] = field(default_factory=dict)


@dataclass(frozen=True)
class EpisodeLog:
    """A validated episode log of one of dynplan's worlds. frames: (T, H, W) uint8; goal: (T, 2) float64 (y, x), None
    for a world without a goal."""

    path: Path
    metadata: dict[str, str]
    config: Config
    seed: int
    frames: np.ndarray
    goal: np.ndarray | None
    agent_start: np.ndarray
    agent: AgentTrack | None
    imagined: dict[int, np.ndarray] | None = None  # replays: {t: (k, H, W) frames the planner predicted at t}

    @property
    def n_frames(self) -> int:
        return len(self.frames)

    @property
    def entry(self) -> World:
        """The world the log records (its `world` metadata; the road where it has none)."""
        return world(self.metadata.get("world", DEFAULT_WORLD))

    def world(self, config: Config | None = None) -> Recording:
        """The recorded episode as its world's recording (the world's own `Recording`), optionally under
        another config of the same frames (the road's agent speed)."""
        return self.entry.rebuild(config or self.config, self.seed, self.frames, self.goal, self.agent_start)


def _scan(path: Path) -> _Scan:
    """Read every intact record of `path`; stop at the first sign of damage and note it."""
    size = path.stat().st_size
    scan = _Scan(LogListing(path, size, complete=False, problem=None))
    listing = scan.listing
    counts: Counter[str] = Counter()
    try:
        with open(path, "rb") as stream:
            for record in StreamReader(stream, validate_crcs=True, record_size_limit=1 << 30).records:
                if isinstance(record, Schema):
                    scan.schemas[record.id] = record
                elif isinstance(record, Channel):
                    scan.channels[record.id] = record
                elif isinstance(record, Message):
                    channel = scan.channels.get(record.channel_id)
                    if channel is None:
                        raise McapError(f"message on unknown channel id {record.channel_id}")
                    scan.messages.setdefault(channel.topic, []).append(record)
                    counts[channel.topic] += 1
                elif isinstance(record, Metadata):
                    listing.metadata[record.name] = dict(record.metadata)
                elif isinstance(record, DataEnd | Footer):
                    listing.complete = isinstance(record, Footer)
    except (EndOfFile, struct.error):
        listing.problem = f"the file ends in the middle of a record after {size} bytes"
    except Exception as error:  # a damaged stream can fail anywhere: mcap, struct, zstd
        listing.problem = f"{type(error).__name__}: {error}"
    for channel in scan.channels.values():
        schema = scan.schemas.get(channel.schema_id)
        listing.topics[channel.topic] = (schema.name if schema else channel.message_encoding, counts[channel.topic])
    return scan


def inspect_log(path: str | os.PathLike) -> LogListing:
    """List what is intact in `path` (never raises for damaged files; raises LogError if it is unreadable)."""
    path = Path(path)
    _check_file(path)
    return _scan(path).listing


def _check_file(path: Path) -> None:
    if not path.exists():
        raise LogError(path, "no such file")
    if not path.is_file():
        raise LogError(path, "not a regular file")
    size = path.stat().st_size
    if size == 0:
        raise LogError(path, "empty file (0 bytes), not an MCAP log")
    with open(path, "rb") as stream:
        magic = stream.read(len(MCAP_MAGIC))
    if magic != MCAP_MAGIC:
        raise LogError(path, f"not an MCAP file (starts with {magic[:8]!r}, expected {MCAP_MAGIC!r})")


def _decode(scan: _Scan, topic: str, expected_schema: str) -> list[Any]:
    records = scan.messages.get(topic, [])
    channel = next((c for c in scan.channels.values() if c.topic == topic), None)
    if channel is None:
        raise LogError(scan.listing.path, f"no {topic} topic; not a dynplan episode log ({scan.listing.describe()})")
    schema = scan.schemas.get(channel.schema_id)
    if schema is None or schema.name != expected_schema:
        found = schema.name if schema else "no schema"
        raise LogError(scan.listing.path, f"topic {topic} has schema {found!r}, expected {expected_schema!r}")
    try:
        decode = DecoderFactory().decoder_for(channel.message_encoding, schema)
        if decode is None:
            raise McapError(f"cannot decode encoding {channel.message_encoding!r} with schema {schema.encoding!r}")
        return [decode(r.data) for r in records]
    except Exception as error:
        raise LogError(scan.listing.path, f"cannot decode {topic} with its embedded schema: {error}") from None


def _metadata(scan: _Scan) -> dict[str, str]:
    path = scan.listing.path
    meta = scan.listing.metadata.get(METADATA_NAME)
    if meta is None:
        raise LogError(path, f"no '{METADATA_NAME}' metadata; not a dynplan episode log ({scan.listing.describe()})")
    if meta.get("format") != FORMAT:
        raise LogError(path, f"metadata format is {meta.get('format')!r}, expected {FORMAT!r}")
    if meta.get("format_version") != FORMAT_VERSION:
        raise LogError(path, f"format version {meta.get('format_version')!r}; this dynplan reads {FORMAT_VERSION!r}")
    return meta


def read_episode_log(path: str | os.PathLike) -> EpisodeLog:
    """Read and validate an episode log written by `write_episode_log`."""
    path = Path(path)
    _check_file(path)
    scan = _scan(path)
    listing = scan.listing
    if listing.problem or not listing.complete:
        what = listing.problem or "it ends before the MCAP footer"
        raise LogError(path, f"truncated or corrupt: {what}; {listing.describe()}")
    meta = _metadata(scan)
    try:
        entry = world(meta.get("world", DEFAULT_WORLD))
        config = entry.config(json.loads(meta["config"]))
        seed, n_frames = entry.check_seed(int(meta["seed"])), int(meta["n_frames"])
        height, width = int(meta["height"]), int(meta["width"])
        agent_start = np.array(json.loads(meta["agent_start"]), dtype=np.float64)
    except (KeyError, ValueError, TypeError, ConfigError) as error:
        raise LogError(path, f"bad '{METADATA_NAME}' metadata: {error}") from None
    if (height, width) != (config.height, config.width) or n_frames < 1 or agent_start.shape != (2,):
        raise LogError(
            path,
            f"bad '{METADATA_NAME}' metadata: height {height}, width {width}, n_frames {n_frames} "
            f"and agent_start {meta['agent_start']} do not describe an episode of its config "
            f"({config.height}×{config.width}, at least 1 frame, a start [y, x])",
        )

    frames, goal = _world_topics(scan, entry, config, n_frames)
    agent = _agent_track(scan) if TOPIC_AGENT_POSE in listing.topics else None
    imagined = _imagined(scan, height, width) if TOPIC_IMAGINED in listing.topics else None
    return EpisodeLog(path, meta, config, seed, frames, goal, agent_start, agent, imagined)


def _world_topics(scan: _Scan, entry: World, config: Config, n_frames: int) -> tuple[np.ndarray, ...]:
    """The world's frames (T, H, W) and goal track (T, 2; None for a world without a goal), once each topic is
    found to hold frames 0 … T−1 in order, at their log times, with frames of the log's size holding only the
    world's pixel values."""
    path, height, width = scan.listing.path, config.height, config.width
    images = _decode(scan, TOPIC_FRAME, SCHEMA_FRAME)
    if not entry.has_goal and TOPIC_GOAL in scan.listing.topics:
        raise LogError(path, f"has a {TOPIC_GOAL} topic, but the {entry.name} world has no goal")
    goals = _decode(scan, TOPIC_GOAL, SCHEMA_POSE) if entry.has_goal else images
    for topic in (TOPIC_FRAME, TOPIC_GOAL) if entry.has_goal else (TOPIC_FRAME,):
        problem = _order_problem(scan.messages.get(topic, []))
        if problem:
            raise LogError(path, f"{topic} {problem}")
    if len(images) != n_frames or len(goals) != n_frames:
        poses = f" and {len(goals)} goal poses" if entry.has_goal else ""
        raise LogError(path, f"has {len(images)} frames{poses}; metadata says {n_frames}")
    for t, im in enumerate(images):
        if (im.height, im.width, im.encoding, im.step, len(im.data)) != (height, width, "mono8", width, height * width):
            raise LogError(
                path,
                f"{TOPIC_FRAME} message {t} is {im.height}×{im.width} {im.encoding} (step {im.step}, "
                f"{len(im.data)} bytes), expected {height}×{width} mono8 (step {width}, "
                f"{height * width} bytes)",
            )
    frames = np.frombuffer(b"".join(im.data for im in images), np.uint8).reshape(n_frames, height, width)[:, ::-1]
    values = sorted(set(entry.pixel_values(config).values()))
    allowed = np.zeros(256, dtype=bool)
    allowed[values] = True
    outside = ~allowed[frames]
    if outside.any():
        t, y, x = (int(i) for i in np.argwhere(outside)[0])
        raise LogError(
            path,
            f"{TOPIC_FRAME} message {t} has pixel value {frames[t, y, x]} at (y {y}, x {x}); "
            f"the world's pixel values are {', '.join(map(str, values))}",
        )
    if not entry.has_goal:
        return np.ascontiguousarray(frames), None
    goal = np.array([(g.pose.position.y, g.pose.position.x) for g in goals], dtype=np.float64)
    if not np.isfinite(goal).all():
        raise LogError(path, f"{TOPIC_GOAL} message {int(np.argwhere(~np.isfinite(goal))[0, 0])} is not finite")
    return np.ascontiguousarray(frames), goal


def _order_problem(records: list[Message]) -> str | None:
    """What is wrong with the order of a world topic's messages (None: message t is frame t, by its sequence
    number and by its log and publish times, for every t)."""
    times = np.fromiter((r.log_time for r in records), np.int64, len(records))
    published = np.fromiter((r.publish_time for r in records), np.int64, len(records))
    if (published != times).any():
        i = int(np.flatnonzero(published != times)[0])
        return f"message {i} has publish time {published[i]} ns, not its log time {times[i]} ns"
    off_clock = (times - EPOCH_NS) % FRAME_PERIOD_NS != 0
    if off_clock.any():
        i = int(np.flatnonzero(off_clock)[0])
        return f"message {i} has log time {times[i]} ns, off the frame clock (epoch {EPOCH_NS} + t · {FRAME_PERIOD_NS})"
    sequence = np.fromiter((r.sequence for r in records), np.int64, len(records))
    for label, values in (("sequence", sequence), ("the log time of frame", (times - EPOCH_NS) // FRAME_PERIOD_NS)):
        problem = _sequence_problem(label, values)
        if problem:
            return problem
    return None


def _sequence_problem(label: str, values: np.ndarray) -> str | None:
    """Why `values` is not 0, 1, 2, …: a step back (out of order), a repeat, or a gap (frames missing)."""
    if len(values) == 0:
        return None
    step = np.diff(values)
    for bad, what in ((step < 0, "frames out of order"), (step == 0, "a repeated frame"), (step > 1, "missing")):
        if bad.any():
            i = int(np.flatnonzero(bad)[0]) + 1
            before, now = int(values[i - 1]), int(values[i])
            what = what if what != "missing" else _missing(before + 1, now - 1)
            return f"message {i} has {label} {now} after {before} ({what})"
    if values[0] != 0:
        return f"message 0 has {label} {int(values[0])}, expected 0 ({_missing(0, int(values[0]) - 1)})"
    return None


def _missing(first: int, last: int) -> str:
    return f"frame {first} missing" if first == last else f"frames {first}–{last} missing"


def _imagined(scan: _Scan, height: int, width: int) -> dict[int, np.ndarray]:
    """A replay's predicted frames per decision: {t: (k, H, W)}, each strip k frames of the log's size."""
    strips = _decode(scan, TOPIC_IMAGINED, SCHEMA_FRAME)
    imagined = {}
    for i, (record, im) in enumerate(zip(scan.messages[TOPIC_IMAGINED], strips, strict=True)):
        if im.height != height or im.width % width or not im.width or len(im.data) != im.height * im.width:
            raise LogError(
                scan.listing.path,
                f"{TOPIC_IMAGINED} message {i} is {im.height}×{im.width} with "
                f"{len(im.data)} bytes, expected {height}×(k·{width}) mono8",
            )
        strip = np.frombuffer(im.data, np.uint8).reshape(im.height, im.width)[::-1]
        t = int((record.log_time - EPOCH_NS) // FRAME_PERIOD_NS)
        imagined[t] = strip.reshape(height, im.width // width, width).transpose(1, 0, 2).copy()
    return imagined


def _agent_track(scan: _Scan) -> AgentTrack:
    poses = _decode(scan, TOPIC_AGENT_POSE, SCHEMA_POSE)
    try:
        steps = [json.loads(r.data) for r in scan.messages.get(TOPIC_AGENT_STEP, [])]
        t = [(r.log_time - EPOCH_NS) // FRAME_PERIOD_NS for r in scan.messages[TOPIC_AGENT_POSE]]
        return AgentTrack(
            t=np.array(t, dtype=np.int64),
            position=np.array([(p.pose.position.y, p.pose.position.x) for p in poses], dtype=np.float64),
            action=np.array([s["action"] for s in steps], dtype=np.int64),
            reward=np.array([s["reward"] for s in steps], dtype=np.float64),
            outcome=tuple(s["outcome"] for s in steps),
        )
    except (KeyError, ValueError, TypeError) as error:
        raise LogError(scan.listing.path, f"bad agent track: {error}") from None
