"""The live view: an episode's topics served over the Foxglove WebSocket protocol while it is played.

The same topics, schemas and message bytes as a replay log (`writer.py`, docs/formats.md §1), so the replay
layout (`format.REPLAY_LAYOUT`) shows a live episode as it shows a recorded one: open the Foxglove app, connect
to `ws://127.0.0.1:8765` ("Open connection" → Foxglove WebSocket) and load the layout. Needs the `live` extra
(the `foxglove-sdk` package).
"""

from __future__ import annotations

import json
import threading
from time import monotonic, sleep

import numpy as np
from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from mcap_protobuf.schema import build_file_descriptor_set

from dynplan.env.colors import draw_agent
from dynplan.extras import require
from dynplan.logs.format import (
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
    log_time,
)
from dynplan.logs.writer import annotations, image_message, imagined_strip, pose_message

#: The Foxglove app's default WebSocket port.
DEFAULT_PORT = 8765
#: Seconds without a new subscription after which a viewer is taken to have subscribed to all it asked for.
SETTLE_S = 0.25


class LiveView:
    """A Foxglove WebSocket server on `host:port` (0: any free port; `port` says which) publishing one episode:
    `show` each frame as it is played. Use it as a context manager, or `close` it."""

    def __init__(self, host: str = "127.0.0.1", port: int = DEFAULT_PORT):
        foxglove = require("foxglove", "live", "the live view")
        self._watched, self._subscribed_at = threading.Event(), 0.0

        class Listener:  # the server calls it from its own threads
            def on_subscribe(_, client: object, channel: object) -> None:
                self._subscribed_at = monotonic()
                self._watched.set()

        self._context = context = foxglove.Context()  # its own channels: views in one process share no topics
        self.server = foxglove.start_server(
            name="dynplan", host=host, port=port, server_listener=Listener(), context=context
        )
        self.host, self.port = host, int(self.server.port)

        def protobuf(topic: str, message: type) -> object:
            data = build_file_descriptor_set(message).SerializeToString()
            schema = foxglove.Schema(name=message.DESCRIPTOR.full_name, encoding="protobuf", data=data)
            return foxglove.Channel(topic, schema=schema, message_encoding="protobuf", context=context)

        def json_rows(topic: str, name: str, json_schema: dict) -> object:
            schema = foxglove.Schema(name=name, encoding="jsonschema", data=json.dumps(json_schema).encode())
            return foxglove.Channel(topic, schema=schema, message_encoding="json", context=context)

        self._frame, self._goal = protobuf(TOPIC_FRAME, RawImage), protobuf(TOPIC_GOAL, PoseInFrame)
        self._pose, self._view = protobuf(TOPIC_AGENT_POSE, PoseInFrame), protobuf(TOPIC_AGENT_VIEW, RawImage)
        self._annotations = protobuf(TOPIC_ANNOTATIONS, ImageAnnotations)
        self._imagined = protobuf(TOPIC_IMAGINED, RawImage)
        self._search = json_rows(TOPIC_SEARCH, "dynplan.Search", SEARCH_JSON_SCHEMA)
        self._step = json_rows(TOPIC_AGENT_STEP, "dynplan.AgentStep", STEP_JSON_SCHEMA)

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    def wait_for_viewer(self, timeout: float, settle: float = SETTLE_S) -> bool:
        """Whether a client subscribed to a topic within `timeout` seconds (at once if one has already); then until
        `settle` seconds pass without another subscription (a viewer subscribes to its panels' topics one after
        another), within the timeout, so that the first messages reach every topic it asked for."""
        end = monotonic() + timeout
        if not self._watched.wait(timeout):
            return False
        while (quiet := monotonic() - self._subscribed_at) < settle and monotonic() < end:
            sleep(max(0.0, min(settle - quiet, end - monotonic())))
        return True

    def show(
        self,
        t: int,
        frame: np.ndarray,
        goal: np.ndarray,
        position: np.ndarray | None = None,
        decision: dict | None = None,
        imagined: np.ndarray | None = None,
        step: dict | None = None,
    ) -> None:
        """Publish frame `t` (H, W) and the goal; with the agent's `position`, its pose, view and the annotations
        over the frame; a `decision` (a /planner/search row), the `imagined` frames (k, H, W) it planned on, and
        the `step` that led to t (an /agent/step row: t, action, reward, outcome)."""
        time = log_time(t)
        if step is not None:
            self._step.log(json.dumps(step).encode(), log_time=time)
        self._frame.log(image_message(t, frame).SerializeToString(), log_time=time)
        self._goal.log(pose_message(t, goal).SerializeToString(), log_time=time)
        if position is not None:
            self._pose.log(pose_message(t, position).SerializeToString(), log_time=time)
            self._view.log(image_message(t, draw_agent(frame, position)).SerializeToString(), log_time=time)
            marks = annotations(t, position, goal, frame.shape[0], decision)
            self._annotations.log(marks.SerializeToString(), log_time=time)
        if decision is not None:
            self._search.log(json.dumps(decision).encode(), log_time=time)
        if imagined is not None:
            self._imagined.log(image_message(t, imagined_strip(imagined)).SerializeToString(), log_time=time)

    def close(self) -> None:
        self.server.stop()

    def __enter__(self) -> LiveView:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
