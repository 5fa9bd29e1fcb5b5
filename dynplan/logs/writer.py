"""Write an episode (and optionally an agent's track through it) as an MCAP log, atomically."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
from foxglove_schemas_protobuf.CircleAnnotation_pb2 import CircleAnnotation
from foxglove_schemas_protobuf.Color_pb2 import Color
from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations
from foxglove_schemas_protobuf.Point2_pb2 import Point2
from foxglove_schemas_protobuf.PointsAnnotation_pb2 import PointsAnnotation
from foxglove_schemas_protobuf.Pose_pb2 import Pose
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from foxglove_schemas_protobuf.TextAnnotation_pb2 import TextAnnotation
from foxglove_schemas_protobuf.Vector3_pb2 import Vector3
from google.protobuf.timestamp_pb2 import Timestamp
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter
from mcap_protobuf.schema import register_schema

from dynplan.env.colors import draw_agent
from dynplan.files import atomic_path
from dynplan.logs.format import (
    FORMAT,
    FORMAT_VERSION,
    FRAME_ID,
    METADATA_NAME,
    SEARCH_JSON_SCHEMA,
    STEP_JSON_SCHEMA,
    TOPIC_AGENT_POSE,
    TOPIC_AGENT_STEP,
    TOPIC_AGENT_VIEW,
    TOPIC_ANNOTATIONS,
    TOPIC_FRAME,
    TOPIC_GOAL,
    TOPIC_IMAGINED,
    TOPIC_SEARCH,
    AgentTrack,
    log_time,
)
from dynplan.world import DEFAULT_WORLD, Recording, world_of

#: Uncompressed bytes per MCAP chunk: about 50 frames, so a truncated log keeps most of its frames readable.
CHUNK_BYTES = 128 * 1024


def _stamp(t: int) -> Timestamp:
    ns = log_time(t)
    return Timestamp(seconds=ns // 10**9, nanos=ns % 10**9)


def pose_message(t: int, yx: np.ndarray) -> PoseInFrame:
    """A world position (y, x) at frame `t` as a foxglove.PoseInFrame (x, y in the world's frame)."""
    position = Vector3(x=float(yx[1]), y=float(yx[0]), z=0.0)
    return PoseInFrame(
        timestamp=_stamp(t), frame_id=FRAME_ID, pose=Pose(position=position, orientation=Quaternion(w=1.0))
    )


def image_message(t: int, frame: np.ndarray) -> RawImage:
    """Frame `t` (H, W) uint8 as a foxglove.RawImage (mono8)."""
    H, W = frame.shape
    # Images are stored top row first; the world's row 0 is the bottom.
    return RawImage(
        timestamp=_stamp(t),
        frame_id=FRAME_ID,
        width=W,
        height=H,
        encoding="mono8",
        step=W,
        data=np.ascontiguousarray(frame[::-1]).tobytes(),
    )


def imagined_strip(frames: np.ndarray) -> np.ndarray:
    """Predicted frames (k, H, W) as one /planner/imagined image (H, k · W), left to right."""
    return np.concatenate(list(frames), axis=1)


def episode_metadata(world: Recording, n_frames: int, kind: str) -> dict[str, str]:
    """The `dynplan` metadata record of a log (all values strings, as MCAP requires). `world` names the world
    unless it is the road, the first (whose logs never carried the key)."""
    from dynplan.version import __version__

    name = world_of(world.config).name
    return {
        **({"world": name} if name != DEFAULT_WORLD else {}),
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


def write_episode_log(
    path: str | os.PathLike,
    world: Recording,
    agent: AgentTrack | None = None,
    n_frames: int | None = None,
    imagined: dict[int, np.ndarray] | None = None,
    search: list[dict] | None = None,
) -> Path:
    """Write `world`'s first `n_frames` frames (default all) and goal track (if it has one) to `path`, plus, for a
    replay, the `agent`'s track (pose, step, its view: the frame with the agent drawn, and annotations over the
    frame), the planner's `imagined` frames per decision ({t: (k, H, W) predicted frames t+1 … t+k}) and its
    `search` rows per decision (`SEARCH_JSON_SCHEMA`: the root's visits, Q and prior, its value and the predicted goal).

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
        goal_channel = None if world.goal is None else writer.register_channel(TOPIC_GOAL, "protobuf", pose_schema)
        writer.add_metadata(METADATA_NAME, episode_metadata(world, n_frames, "world" if agent is None else "agent"))
        for t in range(n_frames):
            time = log_time(t)
            writer.add_message(frame_channel, time, image_message(t, world.frames[t]).SerializeToString(), time, t)
            if goal_channel is not None:
                writer.add_message(goal_channel, time, pose_message(t, world.goal[t]).SerializeToString(), time, t)
        if agent is not None:
            _write_agent(writer, agent, pose_schema)
            view_channel = writer.register_channel(TOPIC_AGENT_VIEW, "protobuf", frame_schema)
            views = draw_agent(world.frames[agent.t], agent.position)
            for i, t in enumerate(agent.t):
                time = log_time(int(t))
                writer.add_message(view_channel, time, image_message(int(t), views[i]).SerializeToString(), time, i)
        if agent is not None:
            decisions = {row["t"]: row for row in search or []}
            annotation_schema = register_schema(writer, ImageAnnotations)
            annotation_channel = writer.register_channel(TOPIC_ANNOTATIONS, "protobuf", annotation_schema)
            for i, t in enumerate(agent.t):
                t, time = int(t), log_time(int(t))
                goal = None if world.goal is None else world.goal[t]
                marks = annotations(t, agent.position[i], goal, world.config.height, decisions.get(t))
                writer.add_message(annotation_channel, time, marks.SerializeToString(), time, i)
        _write_plans(writer, search, imagined, frame_schema)
        writer.finish()
    return Path(path)


def _write_plans(
    writer: McapWriter, search: list[dict] | None, imagined: dict[int, np.ndarray] | None, frame_schema: int
) -> None:
    """The planner's search rows and imagined frames, one message a decision."""
    if search:
        search_json = json.dumps(SEARCH_JSON_SCHEMA).encode()
        search_schema = writer.register_schema("dynplan.Search", "jsonschema", search_json)
        search_channel = writer.register_channel(TOPIC_SEARCH, "json", search_schema)
        for i, row in enumerate(search):
            time = log_time(int(row["t"]))
            writer.add_message(search_channel, time, json.dumps(row).encode(), time, i)
    if imagined:
        imagined_channel = writer.register_channel(TOPIC_IMAGINED, "protobuf", frame_schema)
        for i, (t, frames) in enumerate(sorted(imagined.items())):
            time = log_time(t)
            writer.add_message(
                imagined_channel, time, image_message(t, imagined_strip(frames)).SerializeToString(), time, i
            )


def _write_agent(writer: McapWriter, agent: AgentTrack, pose_schema: int) -> None:
    step_schema = writer.register_schema("dynplan.AgentStep", "jsonschema", json.dumps(STEP_JSON_SCHEMA).encode())
    pose_channel = writer.register_channel(TOPIC_AGENT_POSE, "protobuf", pose_schema)
    step_channel = writer.register_channel(TOPIC_AGENT_STEP, "json", step_schema)
    for i, t in enumerate(agent.t):
        time = log_time(int(t))
        writer.add_message(pose_channel, time, pose_message(int(t), agent.position[i]).SerializeToString(), time, i)
        if i > 0:
            writer.add_message(step_channel, time, json.dumps(agent.step_row(i - 1)).encode(), time, i)


AGENT_COLOUR = Color(r=1.0, g=0.2, b=0.2, a=1.0)
GOAL_COLOUR = Color(r=1.0, g=0.9, b=0.1, a=1.0)
PREDICTED_GOAL_COLOUR = Color(r=1.0, g=0.55, b=0.0, a=1.0)
ACTION_COLOUR = Color(r=1.0, g=1.0, b=1.0, a=1.0)


def _point(y: float, x: float, height: int) -> Point2:
    """World (y, x), row 0 at the bottom and pixel centres on integers → image coordinates (pixel corners on
    integers, row 0 at the top)."""
    return Point2(x=float(x) + 0.5, y=height - 0.5 - float(y))


def _block(lower_left: np.ndarray, height: int, colour: Color, t: int) -> PointsAnnotation:
    """The outline of a 2 × 2 goal block whose lower-left pixel is at world (y, x)."""
    y, x = float(lower_left[0]), float(lower_left[1])
    corners = [(x, height - 2 - y), (x + 2, height - 2 - y), (x + 2, height - y), (x, height - y)]
    return PointsAnnotation(
        timestamp=_stamp(t),
        type=PointsAnnotation.LINE_LOOP,
        outline_color=colour,
        thickness=1,
        points=[Point2(x=a, y=b) for a, b in corners],
    )


def annotations(
    t: int, agent: np.ndarray, goal: np.ndarray | None, height: int, decision: dict | None
) -> ImageAnnotations:
    """What a viewer draws over /world/frame at frame `t`: the agent (a circle), the true goal block, and for a
    decision the predicted goal at t + 1 and the chosen action (an arrow and its heading in degrees)."""
    from dynplan.env.agent import ACTION_ANGLES_DEG

    centre = _point(agent[0], agent[1], height)
    marks = ImageAnnotations(
        circles=[
            CircleAnnotation(
                timestamp=_stamp(t), position=centre, diameter=3.0, thickness=1.0, outline_color=AGENT_COLOUR
            )
        ],
        points=[] if goal is None else [_block(goal, height, GOAL_COLOUR, t)],
    )
    if decision is not None:
        if decision.get("goal") is not None:  # a block's centre is its lower-left pixel + 0.5
            aimed = np.array([decision["goal"]["y"], decision["goal"]["x"]]) - 0.5
            marks.points.append(_block(aimed, height, PREDICTED_GOAL_COLOUR, t))
        angle = float(ACTION_ANGLES_DEG[decision["action"]])
        tip = Point2(x=centre.x + 4 * np.cos(np.deg2rad(angle)), y=centre.y - 4 * np.sin(np.deg2rad(angle)))
        marks.points.append(
            PointsAnnotation(
                timestamp=_stamp(t),
                type=PointsAnnotation.LINE_LIST,
                points=[centre, tip],
                outline_color=ACTION_COLOUR,
                thickness=1,
            )
        )
        marks.texts.append(
            TextAnnotation(
                timestamp=_stamp(t),
                position=Point2(x=1.0, y=1.0),
                font_size=4.0,
                text=f"t={t} action {decision['action']} ({angle:g}°)",
                text_color=ACTION_COLOUR,
            )
        )
    return marks
