"""Write an episode (and optionally an agent's track through it) as an MCAP log, atomically."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
from foxglove_schemas_protobuf.Pose_pb2 import Pose
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from foxglove_schemas_protobuf.Vector3_pb2 import Vector3
from google.protobuf.timestamp_pb2 import Timestamp
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter
from mcap_protobuf.schema import register_schema

from dynplan.env.road import World
from dynplan.files import atomic_path
from dynplan.logs.format import (
    FORMAT,
    FORMAT_VERSION,
    FRAME_ID,
    METADATA_NAME,
    STEP_JSON_SCHEMA,
    TOPIC_AGENT_POSE,
    TOPIC_AGENT_STEP,
    TOPIC_AGENT_VIEW,
    TOPIC_FRAME,
    TOPIC_GOAL,
    TOPIC_IMAGINED,
    AgentTrack,
    log_time,
)
from dynplan.render import draw_agent

#: Uncompressed bytes per MCAP chunk: about 50 frames, so a truncated log keeps most of its frames readable.
CHUNK_BYTES = 128 * 1024


def _stamp(t: int) -> Timestamp:
    ns = log_time(t)
    return Timestamp(seconds=ns // 10**9, nanos=ns % 10**9)


def _pose(t: int, yx: np.ndarray) -> PoseInFrame:
    position = Vector3(x=float(yx[1]), y=float(yx[0]), z=0.0)
    return PoseInFrame(
        timestamp=_stamp(t), frame_id=FRAME_ID, pose=Pose(position=position, orientation=Quaternion(w=1.0))
    )


def _image(t: int, frame: np.ndarray) -> RawImage:
    H, W = frame.shape
    # Images are stored top row first; the world's row 0 is the bottom.
    return RawImage(timestamp=_stamp(t), frame_id=FRAME_ID, width=W, height=H, encoding="mono8", step=W,
                    data=np.ascontiguousarray(frame[::-1]).tobytes())  # fmt: skip


def episode_metadata(world: World, n_frames: int, kind: str) -> dict[str, str]:
    """The `dynplan` metadata record of a log (all values strings, as MCAP requires)."""
    from dynplan.version import __version__

    return {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "kind": kind,
        "config": json.dumps(world.config.model_dump(), sort_keys=True),
        "seed": str(world.seed),
        "height": str(world.config.height),
        "width": str(world.config.width),
        "n_frames": str(n_frames),
        "agent_start": json.dumps([float(v) for v in world.agent_start]),
        "dynplan_version": __version__,
    }


def write_episode_log(path: str | os.PathLike, world: World, agent: AgentTrack | None = None,
                      n_frames: int | None = None, imagined: dict[int, np.ndarray] | None = None) -> Path:  # fmt: skip
    """Write `world`'s first `n_frames` frames (default all) and goal track to `path`, plus, for a replay, the
    `agent`'s track (pose, step, and its view: the frame with the agent drawn) and the planner's `imagined`
    frames per decision ({t: (k, H, W) predicted frames t+1 … t+k}).

    The file appears only when complete (temporary file, then rename).
    """
    n_frames = len(world.frames) if n_frames is None else n_frames
    if not 1 <= n_frames <= len(world.frames):
        raise ValueError(f"n_frames must be in [1, {len(world.frames)}], got {n_frames}")
    with atomic_path(path) as tmp, open(tmp, "wb") as stream:
        writer = McapWriter(stream, compression=CompressionType.ZSTD, chunk_size=CHUNK_BYTES)
        writer.start(profile="", library="dynplan")
        frame_schema = register_schema(writer, RawImage)
        pose_schema = register_schema(writer, PoseInFrame)
        frame_channel = writer.register_channel(TOPIC_FRAME, "protobuf", frame_schema)
        goal_channel = writer.register_channel(TOPIC_GOAL, "protobuf", pose_schema)
        writer.add_metadata(METADATA_NAME, episode_metadata(world, n_frames, "world" if agent is None else "agent"))
        for t in range(n_frames):
            time = log_time(t)
            writer.add_message(frame_channel, time, _image(t, world.frames[t]).SerializeToString(), time, t)
            writer.add_message(goal_channel, time, _pose(t, world.goal[t]).SerializeToString(), time, t)
        if agent is not None:
            _write_agent(writer, agent, pose_schema)
            view_channel = writer.register_channel(TOPIC_AGENT_VIEW, "protobuf", frame_schema)
            views = draw_agent(world.frames[agent.t], agent.position)
            for i, t in enumerate(agent.t):
                time = log_time(int(t))
                writer.add_message(view_channel, time, _image(int(t), views[i]).SerializeToString(), time, i)
        if imagined:
            imagined_channel = writer.register_channel(TOPIC_IMAGINED, "protobuf", frame_schema)
            for i, (t, frames) in enumerate(sorted(imagined.items())):
                strip = np.concatenate(list(frames), axis=1)  # (H, k·W): predicted frames left to right
                time = log_time(t)
                writer.add_message(imagined_channel, time, _image(t, strip).SerializeToString(), time, i)
        writer.finish()
    return Path(path)


def _write_agent(writer: McapWriter, agent: AgentTrack, pose_schema: int) -> None:
    step_schema = writer.register_schema("dynplan.AgentStep", "jsonschema", json.dumps(STEP_JSON_SCHEMA).encode())
    pose_channel = writer.register_channel(TOPIC_AGENT_POSE, "protobuf", pose_schema)
    step_channel = writer.register_channel(TOPIC_AGENT_STEP, "json", step_schema)
    for i, t in enumerate(agent.t):
        time = log_time(int(t))
        writer.add_message(pose_channel, time, _pose(int(t), agent.position[i]).SerializeToString(), time, i)
        if i > 0:
            step = {"t": int(t), "action": int(agent.action[i - 1]), "reward": float(agent.reward[i - 1]),
                    "outcome": agent.outcome[i - 1]}  # fmt: skip
            writer.add_message(step_channel, time, json.dumps(step).encode(), time, i)
