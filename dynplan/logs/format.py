"""The episode log format: one MCAP file per episode, Foxglove protobuf schemas, dynplan metadata.

Topics (log time = EPOCH + t · FRAME_PERIOD; each message's own timestamp is equal to it):

| topic          | schema              | one per | content                                                   |
| -------------- | ------------------- | ------- | --------------------------------------------------------- |
| /world/frame   | foxglove.RawImage   | frame   | mono8 world frame, image row 0 = world row H−1 (top)       |
| /world/goal    | foxglove.PoseInFrame| frame   | goal block's lower-left corner: position.x = col, .y = row |
| /agent/pose    | foxglove.PoseInFrame| step    | (optional) agent position, same axes                       |
| /agent/step    | JSON (jsonschema)   | step    | (optional) {t, action, reward, outcome}                    |
| /agent/view    | foxglove.RawImage   | step    | (optional) the world frame with the agent drawn (value 200) |
| /planner/imagined | foxglove.RawImage | decision| (optional) the k predicted frames t+1 … t+k, side by side   |
| /planner/search | JSON (jsonschema) | decision | (optional) the root: visits, Q, prior per action; value; goal |
| /world/annotations | foxglove.ImageAnnotations | step | (optional) agent, true and predicted goal, action |

A world without a goal (`dynplan.world.World.has_goal`) has no /world/goal topic.

Every JSON schema is one that Foxglove's schema parser takes: one type per field, objects with their properties
(a field that may be missing is left out of `required`, never typed as a union with null).

The metadata record `dynplan` holds the format and version, the world's name (`world`; absent for the road, the
first world), its config (JSON), seed, height, width, n_frames, agent_start (JSON) and the dynplan version. Log
times start at a fixed epoch rather than the wall clock, so the same seed always gives the same bytes and a log's
checksum identifies its episode.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

FORMAT = "dynplan.episode"
FORMAT_VERSION = "1"
METADATA_NAME = "dynplan"

TOPIC_FRAME = "/world/frame"
TOPIC_GOAL = "/world/goal"
TOPIC_AGENT_POSE = "/agent/pose"
TOPIC_AGENT_STEP = "/agent/step"
TOPIC_AGENT_VIEW = "/agent/view"
TOPIC_IMAGINED = "/planner/imagined"
TOPIC_SEARCH = "/planner/search"
TOPIC_ANNOTATIONS = "/world/annotations"

SCHEMA_FRAME = "foxglove.RawImage"
SCHEMA_POSE = "foxglove.PoseInFrame"
FRAME_ID = "world"

#: 2018-07-10T00:00:00Z, the first day of ICML 2018: a fixed start so that logs are byte-reproducible.
EPOCH_NS = 1_531_180_800 * 10**9
#: 10 frames per second of log time.
FRAME_PERIOD_NS = 100_000_000

MCAP_MAGIC = b"\x89MCAP0\r\n"

STEP_JSON_SCHEMA = {
    "title": "dynplan.AgentStep",
    "type": "object",
    "properties": {
        "t": {"type": "integer", "description": "frame index the agent arrived on"},
        "action": {"type": "integer", "description": "action index 0-7 (heading -180 + 45*i degrees)"},
        "reward": {"type": "number"},
        "outcome": {"type": "string", "enum": ["running", "goal", "death", "timeout"]},
    },
    "required": ["t", "action", "reward", "outcome"],
}


SEARCH_JSON_SCHEMA = {
    "title": "dynplan.Search",
    "type": "object",
    "properties": {
        "t": {"type": "integer", "description": "frame index of the decision"},
        "action": {"type": "integer", "description": "the action chosen, 0-7"},
        "visits": {"type": "array", "items": {"type": "integer"}, "description": "root visits per action"},
        "q": {"type": "array", "items": {"type": "number"}, "description": "root mean value per action"},
        "prior": {"type": "array", "items": {"type": "number"}, "description": "root prior per action"},
        "value": {"type": "number", "description": "the root's value: Q averaged over the visits"},
        "goal": {
            "type": "object",
            "properties": {"x": {"type": "number"}, "y": {"type": "number"}},
            "required": ["x", "y"],
            "description": "predicted goal centre at t + 1 (x = col, y = row); absent where the prediction shows none",
        },
        "search_ms": {"type": "number", "description": "the search's milliseconds (the prediction's not counted)"},
    },
    "required": ["t", "action", "visits", "q", "prior", "value", "search_ms"],
}


def log_time(t: int) -> int:
    """Log time in nanoseconds of frame index `t`."""
    return EPOCH_NS + int(t) * FRAME_PERIOD_NS


def step_row(t: int, action: int, reward: float = 0.0, outcome: str = "running") -> dict:
    """An /agent/step row (`STEP_JSON_SCHEMA`): the step that led to frame `t`."""
    return {"t": int(t), "action": int(action), "reward": float(reward), "outcome": outcome}


@dataclass(frozen=True)
class AgentTrack:
    """An agent acting in an episode: its pose at each frame it occupied, and each step it took.

    t:        (N,) frame indices, the first being the start frame (no action led there)
    position: (N, 2) float64 continuous (y, x)
    action:   (N−1,) action taken to reach t[1:]
    reward:   (N−1,) reward of each step
    outcome:  (N−1,) "running", "goal", "death" or "timeout" after each step
    """

    t: np.ndarray
    position: np.ndarray
    action: np.ndarray
    reward: np.ndarray
    outcome: tuple[str, ...]

    def step_row(self, i: int) -> dict:
        """Step i's /agent/step row (it led to frame t[i + 1]); negative i counts from the last."""
        i = i % len(self.action)
        return step_row(self.t[i + 1], self.action[i], self.reward[i], self.outcome[i])

    def __post_init__(self) -> None:
        n = len(self.t)
        if self.position.shape != (n, 2) or len(self.action) != n - 1 or len(self.reward) != n - 1:
            raise ValueError(
                f"AgentTrack: {n} poses need positions (N, 2) and N−1 actions/rewards/outcomes; got "
                f"{self.position.shape}, {len(self.action)}, {len(self.reward)}, {len(self.outcome)}"
            )
        if len(self.outcome) != n - 1:
            raise ValueError(f"AgentTrack: {n} poses need {n - 1} outcomes, got {len(self.outcome)}")


#: The Foxglove layout shipped for replay logs: the world frame with its annotations, the imagined frames, the
#: agent's view, the search's statistics and the agent's path (open it in Foxglove: Layouts → Import). Its image
#: panels are the `Image` panel of the current Foxglove app and of Lichtblick.
REPLAY_LAYOUT = Path(__file__).parent / "layouts" / "replay.json"
#: The same layout for the open-source Foxglove Studio 1.48 that `flows.view` serves, whose image panel is
#: `ImageViewPanel` (its `Image` panel is an experimental one that draws nothing without a setting).
STUDIO_LAYOUT = Path(__file__).parent / "layouts" / "replay-studio-1.48.json"


def _image_panel(config: dict) -> tuple[str, list[str]] | None:
    """An image panel's image topic and annotation topics, in either dialect (`Image`'s `imageMode`, Studio 1.48's
    `ImageViewPanel`); None for another panel."""
    if "imageTopic" in config.get("imageMode", {}):
        return config["imageMode"]["imageTopic"], list(config["imageMode"].get("annotations", {}))
    if "cameraTopic" in config:
        return config["cameraTopic"], list(config.get("enabledMarkerTopics", []))
    return None


def panel_topics(layout: str | os.PathLike = REPLAY_LAYOUT) -> dict[str, set[str]]:
    """The topics each panel of a Foxglove layout reads (by panel id): image and annotation topics of image panels
    (either dialect), the topics of plots' and raw messages' paths."""
    panels = {}
    for key, config in json.loads(Path(layout).read_text())["configById"].items():
        image = _image_panel(config)
        topics = {image[0], *image[1]} if image else set()
        paths = [p["value"] for p in config.get("paths", [])] + ([config["topicPath"]] if "topicPath" in config else [])
        panels[key] = topics | {path.split(".")[0] for path in paths}
    return panels


def layout_topics(layout: str | os.PathLike = REPLAY_LAYOUT) -> set[str]:
    """The topics a Foxglove layout's panels read."""
    return set().union(*panel_topics(layout).values())
