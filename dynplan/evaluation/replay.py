"""Replay a recorded episode through a planner: the outcome, a replay log Foxglove can show, and a GIF.

The GIF follows the reference's figure: per decision, the observed frame with the agent, the true frame k steps
ahead, the model's prediction of it, and their difference (false negatives red, false positives blue, true
goal yellow, predicted goal orange).
"""

from __future__ import annotations

import os
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from dynplan.env.agent import FIRST_DECISION_FRAME
from dynplan.env.colors import colorize
from dynplan.env.config import RoadConfig
from dynplan.evaluation.techniques import TECHNIQUES, AgentInputs, learned_model, technique
from dynplan.logs.format import step_row
from dynplan.logs.live import LiveView
from dynplan.logs.reader import EpisodeLog, LogError, read_episode_log
from dynplan.logs.writer import write_episode_log
from dynplan.models.registry import WORLD_MODELS
from dynplan.planning.episode import run_episode
from dynplan.planning.forward import Prediction
from dynplan.planning.mcts import Decision, MCTSConfig, MCTSPlanner, RandomPlanner
from dynplan.render import error_image, side_by_side, write_gif


def planners() -> list[str]:
    """What a replay's planner may be: any registered technique, or "model" (the learned world model with the
    samples and futures given)."""
    return [*TECHNIQUES, "model"]


def prepare(
    log: str | os.PathLike,
    planner: str,
    agent_speed: float,
    rollout_steps: int,
    playouts: int,
    model: str = "default",
    samples: int = 0,
    futures: int = 0,
    model_dir: str | None = None,
) -> tuple[EpisodeLog, RoadConfig, MCTSConfig]:
    """Check a replay's inputs before running it: the log (LogError), the options (ConfigError/ValueError), and
    for the learned model its checkpoints (CheckpointError)."""
    if planner not in planners():
        raise ValueError(f"planner must be one of {planners()}, got {planner!r}")
    if planner == "model" or technique(planner).world_model:
        if model not in WORLD_MODELS or samples < 0 or futures < 0:
            raise ValueError(f"model must be one of {list(WORLD_MODELS)} and samples, futures >= 0; got "
                             f"{model!r}, {samples}, {futures}")  # fmt: skip
        learned_model(
            model, samples, 0, futures, model_dir
        )  # loads (and caches) the checkpoints, or says which are missing
    mcts = MCTSConfig(rollout_steps=rollout_steps, playouts=playouts)
    config = RoadConfig(agent_speed=agent_speed)  # validates the speed before the log is read
    recorded = read_episode_log(log)
    config = RoadConfig.from_dict(recorded.config.model_dump(), agent_speed=agent_speed)
    if config.max_steps > recorded.n_frames:
        raise LogError(log, f"holds {recorded.n_frames} frames; agent speed {agent_speed:g} needs {config.max_steps}")
    return recorded, config, mcts


@dataclass(frozen=True)
class ReplayResult:
    """What happened, how long decisions took, and where the outputs went."""

    log: str
    planner: str
    agent_speed: float
    rollout_steps: int
    outcome: str
    steps: int
    decision_ms_median: float
    decision_ms_mean: float
    out: str | None
    gif: str | None

    def to_dict(self) -> dict:
        return asdict(self)


def replay(log: str | os.PathLike, planner: str = "oracle", agent_speed: float = 1.0, rollout_steps: int = 3,
           playouts: int = 100, out: str | os.PathLike | None = None, gif: str | os.PathLike | None = None,
           seed: int = 0, model: str = "default", samples: int = 0, futures: int = 0,
           model_dir: str | None = None, live: LiveView | None = None,
           pace_s: float = 0.0) -> ReplayResult:  # fmt: skip
    """Run `planner` (a registered technique — oracle, zero, random, mid, samples5, … with world model `model` for
    a learned one — or "model": the learned world model `model` merging `samples` decoder samples and `futures`
    sampled futures; its checkpoints under `model_dir/<model>/` if given, else the committed ones) on the episode
    recorded in `log`. `live`: also publish every frame and decision there as it is planned, at least `pace_s`
    seconds apart (a viewer follows the episode)."""
    recorded, config, mcts = prepare(log, planner, agent_speed, rollout_steps, playouts, model, samples, futures,
                                     model_dir)  # fmt: skip
    world = recorded.world()
    if learned := planner == "model":
        forward = learned_model(model, samples, seed, futures, model_dir)
    else:
        chosen = technique(planner)
        forward = chosen.forward(AgentInputs(world, model if chosen.world_model else None, seed, model_dir))
    searches = learned or technique(planner).search
    agent = MCTSPlanner(mcts, agent_speed, config.max_steps, seed) if searches else RandomPlanner(seed)
    imagined: dict[int, np.ndarray] = {}
    search: list[dict] = []
    panels: list[np.ndarray] = []

    shown = [time.perf_counter()]

    def record(t: int, position: np.ndarray, prediction: Prediction | None, decision: Decision) -> None:
        search.append(search_row(t, prediction, decision))
        if prediction is not None:
            imagined[t] = prediction.frames
        if gif is not None:
            panels.append(_gif_panel(world.frames, t, position, prediction, rollout_steps))
        if live is not None:
            time.sleep(max(0.0, shown[0] + pace_s - time.perf_counter()))
            step = None if len(search) < 2 else step_row(t, search[-2]["action"])
            live.show(t, world.frames[t], world.goal[t], position, search[-1],
                      None if prediction is None else prediction.frames, step)  # fmt: skip
            shown[0] = time.perf_counter()

    if live is not None:  # the frames observed before the first decision
        for t in range(FIRST_DECISION_FRAME):
            live.show(t, world.frames[t], world.goal[t])

    result = run_episode(world, agent, forward, agent_speed, rollout_steps, on_decision=record)
    if live is not None:  # where the episode ended
        track, last = result.track, int(result.track.t[-1])
        live.show(last, world.frames[last], world.goal[last], track.position[-1], step=track.step_row(-1))
    if out is not None:
        write_episode_log(out, world, agent=result.track, n_frames=config.max_steps, imagined=imagined or None,
                          search=search)  # fmt: skip
    if gif is not None:
        write_gif(gif, np.stack(panels), fps=8, scale=4)
    ms = np.asarray(result.decision_ms)
    return ReplayResult(str(log), planner, agent_speed, rollout_steps, result.outcome, result.steps,
                        round(float(np.median(ms)), 4), round(float(ms.mean()), 4),
                        None if out is None else str(out), None if gif is None else str(gif))  # fmt: skip


def search_row(t: int, prediction: Prediction | None, decision: Decision) -> dict:
    """A decision as the log's /planner/search row: the root's visits, Q and prior per action, its value (Q
    averaged over the visits), the prediction's goal at t + 1 (None where it shows none) and the search's time."""
    visits = np.asarray(decision.visits, np.float64)
    value = float((visits * decision.q).sum() / visits.sum()) if visits.sum() else 0.0
    goal = None
    if prediction is not None and len(prediction.goal) and not np.isnan(prediction.goal[0, 0]):
        goal = {"x": float(prediction.goal[0, 1]), "y": float(prediction.goal[0, 0])}
    return {"t": int(t), "action": int(decision.action), "visits": [int(v) for v in decision.visits],
            "q": [round(float(q), 6) for q in decision.q], "prior": [round(float(p), 6) for p in decision.prior],
            "value": round(value, 6), "goal": goal, "search_ms": round(float(decision.search_ms), 4)}  # fmt: skip


def _gif_panel(frames: np.ndarray, t: int, position: np.ndarray, prediction: Prediction | None, k: int) -> np.ndarray:
    """Observed frame | true frame at the horizon | predicted frame at the horizon | error."""
    h = min(k, len(frames) - 1 - t) if prediction is None else len(prediction.frames)
    truth = frames[t + h]
    predicted = prediction.frames[h - 1] if prediction is not None else np.zeros_like(truth)
    return side_by_side([colorize(frames[t], position), colorize(truth), colorize(predicted),
                         error_image(truth, predicted)])  # fmt: skip


def default_outputs(log: str | os.PathLike, planner: str, model: str = "default", samples: int = 0,
                    futures: int = 0) -> Path:  # fmt: skip
    """Default replay log path: a `replays/` folder beside the input's folder (kept apart from recorded
    episodes, so that a folder of logs stays a folder of worlds), named for the episode and the planner."""
    log = Path(log)
    name = planner if planner != "model" else f"model-{model}-s{samples}-f{futures}"
    return log.parent.parent / "replays" / f"{log.stem}.replay-{name}.mcap"
