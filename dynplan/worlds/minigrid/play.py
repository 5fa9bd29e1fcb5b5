"""One interactive MiniGrid episode, without a window: you (the keys) or the planner choose each step.

The room is recorded from its seed; each step moves the agent (turn left, turn right, forward) and the room one
frame on, judged by the world's rule (`agent.step`). At every step the technique's view of the next k frames is at
hand (`look_ahead`: the true future, a sample of the ball rule, the balls standing still or moving on), whoever
plays. What was played is written as a replay log (`record`). `flows.play --world minigrid` is the window and
keyboard around it: the room now with the agent, the true room k steps on, what the technique sees there (`panels`).
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from dynplan.env.colors import colorize
from dynplan.logs.format import AgentTrack
from dynplan.logs.writer import write_episode_log
from dynplan.render import side_by_side
from dynplan.worlds.minigrid.agent import AGENT_START_POSE, FORWARD, LEFT, RIGHT, Outcome, Pose, step
from dynplan.worlds.minigrid.evaluation import TECHNIQUES, Player, belief
from dynplan.worlds.minigrid.futures import Imagined
from dynplan.worlds.minigrid.grid import MiniGridWorld
from dynplan.worlds.minigrid.results import LEARNED_SAMPLES
from dynplan.worlds.minigrid.search import GridSearch, layout_of, plan_chances

#: The horizons the K key cycles through.
HORIZONS = (3, 5, 6)
#: Key name → the agent's action.
ACTION_KEYS = {"a": LEFT, "left": LEFT, "d": RIGHT, "right": RIGHT, "w": FORWARD, "up": FORWARD}
PLANNERS = tuple(t for t in TECHNIQUES if t != "random")

if TYPE_CHECKING:  # the learned model needs torch: built by the command that plays with it
    from dynplan.worlds.minigrid.imagine import MiniGridModel


class MiniGridPlay:
    """The state of one interactive episode in `room` (a recording: `record_world`, or a log's), planned by
    `technique` (one of `PLANNERS`; `walk` with `samples` futures; a learned one with `model`, the world model) at
    horizon `horizon`."""

    caption = "dynplan play: MiniGrid"
    keys = ACTION_KEYS

    def __init__(
        self,
        room: MiniGridWorld,
        technique: str = "walk",
        horizon: int = 5,
        samples: int = 64,
        model: MiniGridModel | None = None,
    ) -> None:
        if technique not in PLANNERS:
            raise ValueError(f"technique {technique!r} does not plan; choose one of {', '.join(PLANNERS)}")
        if technique in LEARNED_SAMPLES and model is None:
            raise ValueError(f"technique {technique!r} plans with a world model; none was given")
        self.room, self.technique, self.samples = room, technique, samples
        self.search, self.model = GridSearch(horizon=horizon), model
        self.reset()

    def reset(self) -> None:
        """Back to the room's start."""
        self.poses: list[Pose] = [AGENT_START_POSE]
        self.turns: list[int] = []
        self.outcomes: list[str] = []
        self._rng = np.random.default_rng(self.room.seed)
        self._ahead: tuple[int, int, Imagined] | None = None
        self.imagined: dict[int, np.ndarray] = {}  # t → (k, H, W): the first future the planner searched at t

    @property
    def t(self) -> int:
        return len(self.turns)

    @property
    def running(self) -> bool:
        return (not self.outcomes or self.outcomes[-1] == "running") and self.t < len(self.room.frames) - 1

    def look_ahead(self) -> Imagined:
        """The futures the technique searches now: their rooms and chances of a ball (computed once a step)."""
        if self._ahead is None or self._ahead[:2] != (self.t, self.search.horizon):
            player = Player(self.search, self.samples, self._rng, self.model)
            self._ahead = (self.t, self.search.horizon, belief(self.technique, self.room, self.t, player))
        return self._ahead[2]

    def planner_action(self) -> tuple[int, float]:
        start = time.perf_counter()
        ahead, layout = self.look_ahead(), layout_of(self.room.frames[self.t])
        action = plan_chances(self.poses[-1], layout, ahead.balls, self.room.goal[0], self.search).action
        self.imagined[self.t] = ahead.rooms[0, 1:]
        return action, (time.perf_counter() - start) * 1e3

    def step(self, action: int, decision_ms: float | None = None) -> str:
        """Play `action` (0 turn left, 1 turn right, 2 forward); returns how the episode stands after it."""
        if not self.running:
            raise ValueError("the episode has ended; reset to play again")
        if action not in (LEFT, RIGHT, FORWARD):
            raise ValueError(f"action={action} is invalid; valid range [0, 2] (turn left, turn right, forward)")
        pose, outcome = step(self.poses[-1], action, self.room.frames[self.t], self.room.frames[self.t + 1])
        self.poses.append(pose)
        self.turns.append(action)
        ended = outcome == Outcome.RUNNING and self.t >= len(self.room.frames) - 1
        self.outcomes.append("timeout" if ended else outcome.name.lower())
        return self.outcomes[-1]

    def cycle_horizon(self) -> int:
        """The next horizon of `HORIZONS`."""
        k = self.search.horizon
        self.search = GridSearch(horizon=HORIZONS[(HORIZONS.index(k) + 1) % len(HORIZONS)] if k in HORIZONS else 5)
        return self.search.horizon

    def key(self, name: str) -> bool:
        """MiniGrid has no key of its own beyond its moves and the window's."""
        return False

    def close(self) -> None:
        """Nothing is held beyond the episode."""

    def record(self, path: str | os.PathLike) -> Path:
        """The turns played, as a replay log: the room, the agent's track and the first future the planner searched
        at each of its decisions."""
        if not self.turns:
            raise ValueError("nothing was played: no replay to write")
        positions = np.array([[p.row, p.col] for p in self.poses], np.float64)
        rewards = np.array([1.0 if o == "goal" else -1.0 if o == "death" else 0.0 for o in self.outcomes])
        track = AgentTrack(np.arange(len(self.poses)), positions, np.array(self.turns), rewards, tuple(self.outcomes))
        return write_episode_log(path, self.room, agent=track, imagined=self.imagined or None)

    def panels(self) -> list[tuple[np.ndarray, str]]:
        """The room now with the agent, the true room k steps on, and what the technique sees there."""
        k, pose = self.search.horizon, self.poses[-1]
        frames = self.room.frames
        truth = frames[min(self.t + k, len(frames) - 1)]
        ahead = self.look_ahead()
        return [
            (colorize(frames[self.t], np.array([pose.row, pose.col], float)), "the room now"),
            (colorize(truth), f"true, t + {k}"),
            (colorize(ahead.rooms[0, -1]), f"{self.technique} sees, t + {k}"),
            (chance_image(ahead.balls[:, -1].mean(axis=0)), f"its chance of a ball, t + {k}"),
        ]

    def status(self, planner_plays: bool, paused: bool) -> list[str]:
        """The lines under the panels: the step, who plays and how it stands, then the keys."""
        who = ("planner plays" + (" (paused)" if paused else "")) if planner_plays else "you play"
        heading = ("right", "down", "left", "up")[self.poses[-1].heading]
        stands = self.outcomes[-1] if self.outcomes else "running"
        return [
            f"t = {self.t}   {who}   facing {heading}   k = {self.search.horizon}   {stands}",
            "A/LEFT: turn left   D/RIGHT: turn right   W/UP: forward   K: horizon   P: planner/you   SPACE: pause",
        ]


def chance_image(chance: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8: each cell's chance of a ball (H, W, row 0 at the bottom) from black (none) to white (sure),
    upright as `colorize` draws a frame."""
    level = np.round(np.clip(chance, 0.0, 1.0) * 255).astype(np.uint8)
    return np.repeat(np.flipud(level)[..., None], 3, axis=2)


def play_out(state: MiniGridPlay, steps: int) -> list[np.ndarray]:
    """The planner plays `state`'s episode on to its end or `steps` steps; the pictures of its panels side by side
    before each step and after the last."""
    pictures = []
    while state.running and state.t < steps:
        pictures.append(side_by_side([image for image, _ in state.panels()]))
        state.step(state.planner_action()[0])
    return [*pictures, side_by_side([image for image, _ in state.panels()])]
