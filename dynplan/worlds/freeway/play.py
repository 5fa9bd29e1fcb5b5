"""One interactive Freeway episode on the real game, without a window: you (the keys) or a planner choose each step.

The game is turn-based here as the evaluation plays it: the emulator and its NOOP shadow advance one agent step per
action. At every step the technique's view of the next k steps is at hand (`look_ahead`: the oracle's true future,
the lanes Freeway's world model imagines, or empty lanes), whoever plays, so the imagination can be watched beside
the truth. What was played is written as a replay log (`record`), as `flows.replay --world freeway` writes one.
`flows.play --world freeway` is the window and keyboard around it: the panels (`panels`: the lanes now with the
chicken, the true lanes k steps on, those the technique searches there and their error) and the keys (`keys`).
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

from dynplan.env.colors import colorize
from dynplan.logs.writer import write_episode_log
from dynplan.planning.forward import ForwardModel
from dynplan.render import error_image
from dynplan.worlds.freeway.evaluation import OBSERVED, PLANNERS, Turn, check_technique, searched_frames
from dynplan.worlds.freeway.game import (
    ACTIONS,
    Chicken,
    FreewayEpisode,
    FreewayGame,
    FreewayStep,
    chicken_mask,
    record_mode,
)
from dynplan.worlds.freeway.replay import track
from dynplan.worlds.freeway.search import ChickenSearch, plan_chicken

#: The horizons the K key cycles through.
HORIZONS = (4, 8, 16)
#: Key name → the chicken's action (0 NOOP, 1 UP, 2 DOWN).
ACTION_KEYS = {"w": 1, "up": 1, "x": 2, "down": 2, "s": 0}


class FreewayPlay:
    """The state of one interactive episode: the real game (through `FreewayGame`), the turns played, and the
    planner of `technique` (one of `freeway.PLANNERS`; `model` for learned) at horizon `horizon`."""

    def __init__(
        self, episode: FreewayEpisode, technique: str = "oracle", horizon: int = 8, model: ForwardModel | None = None
    ) -> None:
        self.caption, self.keys = "dynplan play: Freeway", ACTION_KEYS
        if technique not in PLANNERS:
            raise ValueError(f"technique {technique!r} does not plan; choose one of {', '.join(PLANNERS)}")
        check_technique(technique, model)
        self.episode, self.technique, self.model = episode, technique, model
        self.search = ChickenSearch(horizon=horizon)
        self.world = record_mode(episode.mode)  # the true lanes of the whole game (the oracle's, and the truth shown)
        self.reset()

    def reset(self) -> None:
        """Back to the episode's first step."""
        self.game = FreewayGame(self.episode)
        self.observed = [self.game.world_frame()]
        self.turns: list[Turn] = []
        self._ahead: tuple[int, int, np.ndarray] | None = None

    @property
    def t(self) -> int:
        return len(self.turns)

    @property
    def chicken(self) -> Chicken:
        return self.game.chicken

    @property
    def running(self) -> bool:
        return not (self.turns and self.turns[-1].step.done)

    @property
    def score(self) -> float:
        return float(sum(turn.step.reward for turn in self.turns))

    @property
    def frame(self) -> np.ndarray:
        """The lanes now."""
        return self.observed[-1]

    def true_frame(self, ahead: int = 0) -> np.ndarray:
        """The true lanes `ahead` steps on (the game's last frame past its end)."""
        return self.world.frames[min(self.episode.noop_start + self.t + ahead, len(self.world.frames) - 1)]

    def look_ahead(self) -> np.ndarray:
        """The lanes the technique searches now: the frame now and the k after it (computed once a step)."""
        if self._ahead is None or self._ahead[:2] != (self.t, self.search.horizon):
            future = self.world.frames[self.episode.noop_start + self.t :] if self.technique == "oracle" else None
            frames = searched_frames(self.observed, self.search, self.technique, future, self.model)
            self._ahead = (self.t, self.search.horizon, frames)
        return self._ahead[2]

    def planner_action(self) -> tuple[int, float]:
        """The planner's action now and the decision's milliseconds (the look ahead's and the search's)."""
        start = time.perf_counter()
        action = plan_chicken(self.chicken, self.look_ahead(), self.search).action
        return action, (time.perf_counter() - start) * 1e3

    def step(self, action: int, decision_ms: float | None = None) -> FreewayStep:
        """Play `action` (0 NOOP, 1 UP, 2 DOWN) on the real game; `decision_ms` when a planner chose it."""
        if not self.running:
            raise ValueError("the game has ended; reset to play again")
        if not 0 <= action < len(ACTIONS):
            raise ValueError(f"action={action} is invalid; valid range [0, {len(ACTIONS) - 1}] ({', '.join(ACTIONS)})")
        chicken, frames = self.chicken, self.look_ahead() if decision_ms is not None else None
        step = self.game.step(action)
        self.turns.append(Turn(chicken, frames, action, decision_ms, step))
        self.observed = [*self.observed[-OBSERVED + 1 :], step.frame]
        return step

    def cycle_horizon(self) -> int:
        """The next horizon of `HORIZONS`."""
        horizon = self.search.horizon
        self.search = ChickenSearch(
            horizon=HORIZONS[(HORIZONS.index(horizon) + 1) % len(HORIZONS)] if horizon in HORIZONS else HORIZONS[0]
        )
        return self.search.horizon

    def record(self, path: str | os.PathLike) -> Path:
        """The turns played, as a replay log: the mode's world, the chicken's track and the planner's lanes."""
        if not self.turns:
            raise ValueError("nothing was played: no replay to write")
        start = self.episode.noop_start
        imagined = {start + i: turn.frames[1:] for i, turn in enumerate(self.turns) if turn.frames is not None}
        return write_episode_log(path, self.world, agent=track(self.turns, start), imagined=imagined or None)

    def key(self, name: str) -> bool:
        """Freeway has no key of its own beyond its moves and the window's."""
        return False

    def close(self) -> None:
        """Nothing is held beyond the episode."""

    def panels(self) -> list[tuple[np.ndarray, str]]:
        """What the window shows: the lanes now with the chicken, the true lanes k steps on, those the technique
        searches there, and their error; RGB images with their titles."""
        k = self.search.horizon
        truth, seen = self.true_frame(k), self.look_ahead()[-1]
        now = colorize(self.frame)
        now[np.flip(chicken_mask(self.frame.shape, self.chicken.y), axis=0)] = 255  # the chicken in white
        return [
            (now, "the lanes now"),
            (colorize(truth), f"true, t + {k}"),
            (colorize(seen), f"{self.technique} sees, t + {k}"),
            (error_image(truth, seen, "freeway"), "error (red: missed, blue: extra)"),
        ]

    def status(self, planner_plays: bool, paused: bool) -> list[str]:
        """The lines under the panels: the step, score and who plays, then the keys."""
        who = ("planner plays" + (" (paused)" if paused else "")) if planner_plays else "you play"
        state = "game over" if not self.running else ("knocked back" if self.chicken.knocked else "")
        return [
            f"t = {self.t}   score {self.score:g}   {who}   k = {self.search.horizon}   {state}",
            "W/UP: up   X/DOWN: down   S: wait   K: horizon   P: planner/you   SPACE: pause   R: restart",
        ]
