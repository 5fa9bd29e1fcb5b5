"""Play one episode of a recorded world with a planner and a forward model — the unit of evaluation."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from dynplan.env.config import RoadConfig
from dynplan.env.road import World
from dynplan.env.road_env import RoadEnv
from dynplan.logs.format import AgentTrack
from dynplan.planning.forward import ForwardModel, Prediction
from dynplan.planning.mcts import Decision, MCTSPlanner, RandomPlanner

#: Called after each decision with (t, position, prediction, decision) — e.g. to record imagined frames.
DecisionHook = Callable[[int, np.ndarray, Prediction | None, Decision], None]


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
    """Play `world` (e.g. read from a log) at `agent_speed` until goal, death or timeout.

    Each decision asks `model` for the next `rollout_steps` frames given the frames observed so far — fewer near
    the end: never past frame T − 1, where the episode times out — (a random planner needs no model) and times
    prediction plus search together.
    """
    config = RoadConfig.from_dict(world.config.model_dump(), agent_speed=agent_speed)
    env = RoadEnv(config=config)
    env.reset(options={"world": world})
    planner.reset()
    times: list[float] = []
    t_list, positions, actions, rewards, outcomes = [env.t], [env.position.copy()], [], [], []
    reward, outcome = 0.0, "running"
    while outcome == "running":
        start = time.perf_counter()
        horizon = min(rollout_steps, config.max_steps - 1 - env.t)  # nothing after the timeout frame counts
        prediction = model.predict(world.frames[: env.t + 1], horizon) if model is not None else None
        decision = planner.act(env.position, env.t, prediction)
        times.append((time.perf_counter() - start) * 1e3)
        if on_decision is not None:
            on_decision(env.t, env.position.copy(), prediction, decision)
        _, reward, _, _, info = env.step(decision.action)
        outcome = info["outcome"]
        t_list.append(env.t)
        positions.append(env.position.copy())
        actions.append(decision.action)
        rewards.append(reward)
        outcomes.append(outcome)
    track = AgentTrack(np.array(t_list), np.array(positions), np.array(actions), np.array(rewards), tuple(outcomes))
    return EpisodeResult(world.seed, outcome, len(actions), float(reward), times, track)
