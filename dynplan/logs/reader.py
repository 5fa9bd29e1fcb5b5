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

from dynplan.config import ConfigError
from dynplan.env.config import RoadConfig
from dynplan.env.road import World
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


class LogError(ValueError):
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
    """A validated episode log. frames: (T, H, W) uint8; goal: (T, 2) float64 (y, x)."""

    path: Path
    metadata: dict[str, str]
    config: RoadConfig
    seed: int
    frames: np.ndarray
    goal: np.ndarray
    agent_start: np.ndarray
    agent: AgentTrack | None
    imagined: dict[int, np.ndarray] | None = None  # replays: {t: (k, H, W) frames the planner predicted at t}

    @property
    def n_frames(self) -> int:
        return len(self.frames)

    def world(self, config: RoadConfig | None = None) -> World:
        """The recorded world as a `World`, optionally under another agent speed (same geometry and traffic)."""
        config = config or self.config
        return World(config, self.seed, self.frames, self.goal, self.agent_start)


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
        config = RoadConfig.from_dict(json.loads(meta["config"]))
        seed, n_frames = int(meta["seed"]), int(meta["n_frames"])
        height, width = int(meta["height"]), int(meta["width"])
        agent_start = np.array(json.loads(meta["agent_start"]), dtype=np.float64)
    except (KeyError, ValueError, ConfigError) as error:
        raise LogError(path, f"bad '{METADATA_NAME}' metadata: {error}") from None

    images = _decode(scan, TOPIC_FRAME, SCHEMA_FRAME)
    goals = _decode(scan, TOPIC_GOAL, SCHEMA_POSE)
    if len(images) != n_frames or len(goals) != n_frames:
        raise LogError(path, f"has {len(images)} frames and {len(goals)} goal poses; metadata says {n_frames}")
    bad = next(
        (i for i, im in enumerate(images) if (im.height, im.width, im.encoding) != (height, width, "mono8")), None
    )
    if bad is not None:
        im = images[bad]
        raise LogError(path, f"frame {bad} is {im.height}×{im.width} {im.encoding}, expected {height}×{width} mono8")
    frames = np.frombuffer(b"".join(im.data for im in images), np.uint8).reshape(n_frames, height, width)[:, ::-1]
    goal = np.array([(g.pose.position.y, g.pose.position.x) for g in goals], dtype=np.float64)
    agent = _agent_track(scan) if TOPIC_AGENT_POSE in listing.topics else None
    imagined = None
    if TOPIC_IMAGINED in listing.topics:
        strips = _decode(scan, TOPIC_IMAGINED, SCHEMA_FRAME)
        records = scan.messages[TOPIC_IMAGINED]
        imagined = {
            int((r.log_time - EPOCH_NS) // FRAME_PERIOD_NS): np.frombuffer(im.data, np.uint8)
            .reshape(im.height, im.width)[::-1]
            .reshape(im.height, im.width // width, width)
            .transpose(1, 0, 2)
            .copy()
            for r, im in zip(records, strips, strict=True)
        }
    return EpisodeLog(path, meta, config, seed, np.ascontiguousarray(frames), goal, agent_start, agent, imagined)


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
