"""Play in the world and in the world model's imagination: the state of one interactive episode, without a window.

A `PlayState` holds one recorded world and the agent in it. Each `step` moves the agent one action, as
`RoadEnv.step` does, in one of two places:

* the **world**: the recorded frames, as an evaluation plays them;
* the **imagination**: frames the learned world model rolls forward, one at a time, from the last four it was
  shown — the real frames at the moment you switched in, then its own predictions. The agent is judged on the
  imagined frame (an imagined obstacle kills, the imagined goal wins), while the true frame of the same time
  stays beside it, so the divergence is there to see. Switching back returns to the real world at the same time
  and position.

Or the planner plays (`planner_action`): the oracle or a learned technique searches k steps ahead, and its
predicted frames are drawn beside the truth. What was played is recorded as a replay log of our schema
(`record`): the world, the agent's track, the imagined frames and the planner's search rows. `flows.play` is the
window and keyboard around it (`flows.worlds.play_window`, every world's), and `commands.Play` the road's options.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from dynplan.env.agent import (
    ACTION_ANGLES_DEG,
    FIRST_DECISION_FRAME,
    N_ACTIONS,
    Outcome,
    action_deltas,
    judge,
    reward_of,
)
from dynplan.env.colors import colorize
from dynplan.env.config import RoadConfig
from dynplan.env.road import World, generate_world
from dynplan.logs.format import AgentTrack
from dynplan.logs.writer import write_episode_log
from dynplan.planning.forward import ForwardModel, Prediction
from dynplan.render import error_image

if TYPE_CHECKING:
    from dynplan.logs.live import LiveView

#: The horizons the planner cycles through (`cycle_horizon`).
HORIZONS = (1, 3, 5, 10)
#: Where a step is played.
PLACES = ("world", "imagination")
#: Key name → heading in degrees (90° is up on screen: row 0 of the world is drawn at the bottom).
MOVE_KEYS = {"w": 90, "e": 45, "d": 0, "c": -45, "x": -90, "z": -135, "a": 180, "q": 135,
             "up": 90, "right": 0, "down": -90, "left": 180}  # fmt: skip
KEY_LINES = [
    "move: W E D C X Z A Q or arrows   I: imagination   K: horizon   P: planner/you   SPACE: pause",
    "R: restart   ESC: quit",
]


def action_of(heading: int) -> int:
    """The action index of a heading in degrees (180 is −180)."""
    angle = -180 if heading == 180 else heading
    return int(np.flatnonzero(angle == ACTION_ANGLES_DEG)[0])


#: Key name → action: the moves of a play window (`dynplan.world_parts.PlayState.keys`).
ACTION_KEYS = {name: action_of(heading) for name, heading in MOVE_KEYS.items()}


@dataclass
class PlayState:
    """One interactive episode on `world` at `agent_speed`. `imagination`: the world model the imagination rolls
    forward (None: the imagination is unavailable); `planner` and `forward`: the searching agent and the forward
    model it plans with, for `planner_action` (None: only you play); `k`: the planner's horizon; `live`: a live
    view every step is shown on (None: none), closed with the state."""

    caption = "dynplan play"
    keys = ACTION_KEYS

    world: World
    agent_speed: float = 1.0
    imagination: ForwardModel | None = None
    planner: object | None = None
    forward: ForwardModel | None = None
    k: int = 3
    place: str = "world"
    t: int = FIRST_DECISION_FRAME
    position: np.ndarray = field(default=None)  # type: ignore[assignment]
    outcome: str = "running"
    _imagined: list[np.ndarray] = field(default_factory=list)
    _track: tuple[list, list, list, list, list] = field(default_factory=lambda: ([], [], [], [], []))
    _recorded: dict[int, np.ndarray] = field(default_factory=dict)
    _search: list[dict] = field(default_factory=list)
    last_prediction: Prediction | None = None
    live: LiveView | None = None

    def __post_init__(self) -> None:
        self.config = RoadConfig.from_dict(self.world.config.model_dump(), agent_speed=self.agent_speed)
        if len(self.world.frames) < self.config.max_steps:
            raise ValueError(
                f"the world holds {len(self.world.frames)} frames; agent speed {self.agent_speed:g} "
                f"needs {self.config.max_steps}"
            )
        if self.k not in HORIZONS:
            raise ValueError(f"k must be one of {HORIZONS}, got {self.k}")
        self._deltas = action_deltas(self.agent_speed)
        self.reset()

    def reset(self) -> None:
        """Back to the start of the episode, in the real world."""
        self.t, self.place, self.outcome = FIRST_DECISION_FRAME, "world", "running"
        self.position = self.world.agent_start.astype(np.float64).copy()
        self._imagined = []
        self._track = ([self.t], [self.position.copy()], [], [], [])
        self._recorded, self._search, self.last_prediction = {}, [], None
        if self.planner is not None and hasattr(self.planner, "reset"):
            self.planner.reset()

    @property
    def running(self) -> bool:
        return self.outcome == "running"

    @property
    def frame(self) -> np.ndarray:
        """The frame the agent is judged on now: the real one, or the imagination's latest."""
        return self._imagined[-1] if self.place == "imagination" else self.world.frames[self.t]

    @property
    def true_frame(self) -> np.ndarray:
        return self.world.frames[self.t]

    def toggle_imagination(self) -> str:
        """Switch between the world and the imagination (rolled forward from the last four real frames) and
        return where the next step is played."""
        if self.imagination is None:
            raise ValueError("no world model to imagine with: play with --model default|paper and its weights")
        if self.place == "world":
            self._imagined = list(self.world.frames[self.t - 3 : self.t + 1])
            self.place = "imagination"
        else:
            self._imagined, self.place = [], "world"
        return self.place

    def cycle_horizon(self) -> int:
        """The planner's next horizon in `HORIZONS`."""
        self.k = HORIZONS[(HORIZONS.index(self.k) + 1) % len(HORIZONS)]
        if self.planner is not None and hasattr(self.planner, "config"):  # a searching planner, not the random one
            self.planner.config = self.planner.config.model_copy(update={"rollout_steps": self.k})
            self.planner.reset()  # its kept subtree was searched to the old horizon
        return self.k

    def planner_action(self) -> tuple[int, float]:
        """The planner's choice at this step and its milliseconds, searching against its forward model's
        prediction of the next k frames (the real frames observed so far are what it sees, as in an evaluation)."""
        if self.planner is None:
            raise ValueError("no planner: play with --watch")
        start = time.perf_counter()
        horizon = min(self.k, self.config.max_steps - 1 - self.t)
        prediction = None if self.forward is None else self.forward.predict(self.world.frames[: self.t + 1], horizon)
        decision = self.planner.act(self.position, self.t, prediction)
        self.last_prediction = prediction
        if prediction is not None:
            from dynplan.evaluation.replay import search_row

            self._recorded[self.t] = prediction.frames
            self._search.append(search_row(self.t, prediction, decision))
        return int(decision.action), 1000.0 * (time.perf_counter() - start)

    def step(self, action: int, decision_ms: float | None = None) -> str:
        """Move one action (0 … 7, headings −180°, −135°, … 135°) and advance one frame of wherever the step is
        played; returns the outcome ("running", "goal", "death" or "timeout"). `decision_ms`: the planner's time
        when it chose the step (None: you did, and its last prediction is no longer this step's)."""
        if not self.running:
            raise ValueError(f"the episode has ended ({self.outcome}); reset it")
        if not 0 <= int(action) < N_ACTIONS:
            raise ValueError(f"action must be an integer in [0, {N_ACTIONS - 1}], got {action!r}")
        self.position = self.position + self._deltas[int(action)]
        self.t += 1
        if self.place == "imagination":
            predicted = self.imagination.predict(np.stack(self._imagined[-4:]), 1).frames[0]
            self._imagined.append(predicted)
            self._recorded.setdefault(self.t - 1, predicted[None])
        outcome = Outcome(judge(self.frame, self.position))
        if outcome == Outcome.RUNNING and self.t >= self.config.max_steps - 1:
            outcome = Outcome.TIMEOUT
        self.outcome = outcome.name.lower()
        t_list, positions, actions, rewards, outcomes = self._track
        t_list.append(self.t)
        positions.append(self.position.copy())
        actions.append(int(action))
        rewards.append(reward_of(outcome))
        outcomes.append(self.outcome)
        if decision_ms is None:
            self.last_prediction = None
        if self.live is not None:
            self._publish()
        return self.outcome

    def _publish(self) -> None:
        """Show the latest step on the live view: the frame it was judged on, the agent, the step, and the
        planner's search and prediction when it chose the step."""
        step = self.track.step_row(-1)
        decision = self._search[-1] if self._search and self._search[-1]["t"] == self.t - 1 else None
        imagined = None if decision is None or self.last_prediction is None else self.last_prediction.frames
        self.live.show(self.t, self.frame, self.world.goal[self.t], self.position, decision, imagined, step)

    def key(self, name: str) -> bool:
        """The road's own key: I switches between the world and the imagination (where there is one)."""
        if name != "i" or self.imagination is None:
            return False
        self.toggle_imagination()
        return True

    @property
    def turns(self) -> list[int]:
        """The actions played so far."""
        return self._track[2]

    def panels(self) -> list[tuple[np.ndarray, str]]:
        """Where you play, the true world, and the imagination's divergence or the planner's prediction."""
        shown = [
            (colorize(self.frame, self.position), f"playing in the {self.place}"),
            (colorize(self.true_frame, self.position), "the true world"),
        ]
        if self.place == "imagination":
            third = (error_image(self.true_frame, self.frame), "imagined vs true (red: missed, blue: extra)")
        elif self.last_prediction is not None:
            ahead = self.last_prediction.frames
            truth = self.world.frames[min(self.t + len(ahead) - 1, len(self.world.frames) - 1)]
            third = (error_image(truth, ahead[-1]), f"predicted t + {len(ahead)} vs true")
        else:
            third = (np.full((*self.true_frame.shape, 3), 20, np.uint8), "")
        return [*shown, third]

    def status(self, planner_plays: bool, paused: bool) -> list[str]:
        """The lines under the panels: the time, who plays, the horizon and the outcome, then the keys."""
        who = ("planner plays" + (" (paused)" if paused else "")) if planner_plays else "you play"
        return [f"t = {self.t}   {who}   k = {self.k}   outcome: {self.outcome}", *KEY_LINES]

    def close(self) -> None:
        """Stop the live view, if any."""
        if self.live is not None:
            self.live.close()

    @property
    def search(self) -> list[dict]:
        """The planner's /planner/search rows so far, one per decision it made."""
        return self._search

    @property
    def track(self) -> AgentTrack:
        t, positions, actions, rewards, outcomes = self._track
        return AgentTrack(
            np.array(t), np.array(positions), np.array(actions, np.int64), np.array(rewards), tuple(outcomes)
        )

    def record(self, path: str | os.PathLike) -> Path:
        """Write what was played as a replay log (`flows.replay` and Foxglove open it): the world, the agent's
        track, the imagined frames ({t: frames}: the planner's predictions, or the imagination's frame at t + 1)
        and the planner's search rows."""
        return write_episode_log(
            path,
            self.world,
            agent=self.track,
            n_frames=self.config.max_steps,
            imagined=self._recorded or None,
            search=self._search or None,
        )


def build_state(
    seed: int | None = None,
    log: str | None = None,
    agent_speed: float = 1.0,
    model: str = "default",
    technique_name: str = "oracle",
    k: int = 3,
    imagination: bool = True,
) -> PlayState:
    """The state of the world of `seed` (default: the first validation episode's) or of the recorded `log`: the
    imagination from the learned world model `model` (its mid-point frames, no caution: the frames as the model
    predicts them), the planner of `technique_name` at horizon k."""
    from dynplan.evaluation.agent import AgentSpec
    from dynplan.evaluation.cases import VALIDATION_SEED_START
    from dynplan.evaluation.protocol import world_agent
    from dynplan.logs.reader import read_episode_log
    from dynplan.logs.recording import check_recorded, of_world

    if log is not None:
        world = check_recorded(of_world(read_episode_log(log), "road")).world()
    else:
        world = generate_world(RoadConfig(agent_speed=agent_speed), VALIDATION_SEED_START if seed is None else seed)
    imagined = None
    if imagination:
        from dynplan.models.world_model import load_world_model

        imagined = load_world_model(model=model, caution={"occupancy": 0.0, "margin": 0})
    agent = AgentSpec(technique=technique_name, model=model, rollout_steps=k)
    planner, forward = world_agent(world, agent, agent_speed)
    return PlayState(world, agent_speed, imagined, planner, forward, k)
