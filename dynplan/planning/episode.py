"""Play recorded worlds with planners and forward models: many episodes in lockstep (`run_episodes`), one world-model
call per step for all of them, or one episode on its own (`run_episode`, the batch of one)."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from dynplan.env.config import RoadConfig
from dynplan.env.road import World
from dynplan.env.road_env import RoadEnv
from dynplan.logs.format import AgentTrack
from dynplan.planning.forward import ForwardModel, Prediction
from dynplan.planning.lockstep import step_together

if TYPE_CHECKING:  # the search compiles with numba: its module is imported by whoever builds a planner
    from dynplan.planning.mcts import Decision, MCTSPlanner, RandomPlanner

#: Called after each decision with (t, position, prediction, decision) — e.g. to record imagined frames.
DecisionHook = Callable[[int, np.ndarray, "Prediction | None", "Decision"], None]


@dataclass
class EpisodeResult:
    """How an episode went: outcome ("goal" | "death" | "timeout"), agent steps taken, per-decision times
    (prediction + search, ms) and the agent's track."""

    seed: int
    outcome: str
    steps: int
    reward: float
    decision_ms: list[float] = field(default_factory=list)
    track: AgentTrack | None = None


def run_episode(
    world: World,
    planner: MCTSPlanner | RandomPlanner,
    model: ForwardModel | None,
    agent_speed: float,
    rollout_steps: int = 1,
    on_decision: DecisionHook | None = None,
) -> EpisodeResult:
    """Play `world` (e.g. read from a log) at `agent_speed` until goal, death or timeout: the batch of one of
    `run_episodes`.

    Each decision asks `model` for the next `rollout_steps` frames given the frames observed so far — fewer near
    the end: never past frame T − 1, where the episode times out — (a random planner needs no model) and times
    prediction plus search together.
    """
    hook = None if on_decision is None else (lambda i, *args: on_decision(*args))
    return run_episodes([world], [planner], [model], agent_speed, rollout_steps, hook)[0]


#: Called after each decision of episode i with (i, t, position, prediction, decision).
BatchDecisionHook = Callable[[int, int, np.ndarray, "Prediction | None", "Decision"], None]


@dataclass
class _Episode:
    """One episode of a lockstep batch: its environment, planner, model and horizon, and its track so far."""

    index: int
    world: World
    planner: MCTSPlanner | RandomPlanner
    model: ForwardModel | None
    horizon: int
    on_decision: BatchDecisionHook | None = None
    env: RoadEnv = field(init=False)
    first: tuple[int, np.ndarray] = field(init=False)  # (t, position) before the first step
    times: list[float] = field(default_factory=list)
    steps: list[tuple] = field(default_factory=list)  # (t, position, action, reward, outcome) after each step

    def start(self, agent_speed: float) -> None:
        config = RoadConfig.from_dict(self.world.config.model_dump(), agent_speed=agent_speed)
        self.env = RoadEnv(config=config)
        self.env.reset(options={"world": self.world})
        self.planner.reset()
        self.first = (self.env.t, self.env.position.copy())

    def observed(self) -> np.ndarray:
        """The recorded world's frames up to now."""
        return self.world.frames[: self.env.t + 1]

    def asks(self) -> int:
        """The frames its prediction may hold: the horizon, never past frame T − 1, where the episode times out."""
        return min(self.horizon, self.env.config.max_steps - 1 - self.env.t)

    def advance(self, prediction: Prediction | None, share_ms: float) -> bool:
        """Decide against `prediction` (its time: `share_ms` of the batch's prediction plus the search) and step;
        whether the episode still runs."""
        env = self.env
        start = time.perf_counter()
        decision = self.planner.act(env.position, env.t, prediction)
        self.times.append(share_ms + (time.perf_counter() - start) * 1e3)
        if self.on_decision is not None:
            self.on_decision(self.index, env.t, env.position.copy(), prediction, decision)
        _, reward, _, _, info = env.step(decision.action)
        self.steps.append((env.t, env.position.copy(), decision.action, reward, info["outcome"]))
        return info["outcome"] == "running"

    def result(self) -> EpisodeResult:
        t, positions, actions, rewards, outcomes = zip(*self.steps, strict=True)
        track = AgentTrack(
            np.array([self.first[0], *t]),
            np.array([self.first[1], *positions]),
            np.array(actions),
            np.array(rewards),
            tuple(outcomes),
        )
        return EpisodeResult(self.world.seed, outcomes[-1], len(actions), float(rewards[-1]), self.times, track)


def _check(worlds: Sequence[World], planners: Sequence, models: Sequence, speeds: list, horizons: list) -> None:
    """A ValueError unless there is one planner, model, speed and horizon per world; a TypeError naming a model
    that is not a ForwardModel."""
    n = len(worlds)
    if not n == len(planners) == len(models):
        raise ValueError(f"run_episodes: {n} worlds, {len(planners)} planners, {len(models)} models")
    if not len(speeds) == len(horizons) == n:
        raise ValueError(f"run_episodes: {n} worlds, {len(speeds)} agent speeds, {len(horizons)} rollout steps")
    wrong = [type(m).__name__ for m in models if m is not None and not isinstance(m, ForwardModel)]
    if wrong:
        raise TypeError(
            f"run_episodes: {wrong[0]} is not a ForwardModel (name, predict, predict_batch, batch_key, "
            "cost): subclass dynplan.planning.forward.ForwardModel"
        )


def run_episodes(
    worlds: Sequence[World],
    planners: Sequence[MCTSPlanner | RandomPlanner],
    models: Sequence[ForwardModel | None],
    agent_speed: float | Sequence[float],
    rollout_steps: int | Sequence[int] = 1,
    on_decision: BatchDecisionHook | None = None,
    on_finish: Callable[[int, EpisodeResult], None] | None = None,
) -> list[EpisodeResult]:
    """Play many episodes in lockstep, episode i with `planners[i]` against `models[i]` at its agent speed and horizon
    (one value for all, or one per episode): at each step every live episode's prediction is asked for at once (one
    batched world-model call per group of models on the same weights — episodes on the same world see the same
    frames, and each distinct observation is predicted once), each planner then chooses, all step, and finished
    episodes leave the batch (`on_finish(i, result)` is called as each does). The world does not depend on the
    agent, a model's draws depend only on what its episode observed and each planner keeps its own random stream, so
    an episode's result does not depend on which others share its batch. An episode's decision time is its share of
    the batched prediction (by what it asked for) plus its own search."""
    n = len(worlds)
    speeds = [agent_speed] * n if np.isscalar(agent_speed) else list(agent_speed)
    horizons = [rollout_steps] * n if np.isscalar(rollout_steps) else list(rollout_steps)
    _check(worlds, planners, models, speeds, horizons)
    each = zip(worlds, planners, models, horizons, strict=True)
    episodes = [_Episode(i, *args, on_decision=on_decision) for i, args in enumerate(each)]
    for episode, speed in zip(episodes, speeds, strict=True):
        episode.start(speed)
    results: list[EpisodeResult | None] = [None] * n
    live = episodes
    while live:
        playing = step_together(live)
        for e in (e for e, still in zip(live, playing, strict=True) if not still):
            results[e.index] = e.result()
            if on_finish is not None:
                on_finish(e.index, results[e.index])
        live = [e for e, still in zip(live, playing, strict=True) if still]
    return results  # type: ignore[return-value]
