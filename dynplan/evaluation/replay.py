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
from typing import TYPE_CHECKING

import numpy as np

from dynplan.env.agent import FIRST_DECISION_FRAME
from dynplan.env.colors import colorize
from dynplan.env.config import RoadConfig
from dynplan.evaluation.agent import LEARNED, AgentSpec
from dynplan.evaluation.techniques import TECHNIQUES
from dynplan.logs.format import step_row
from dynplan.logs.live import LiveView
from dynplan.logs.reader import EpisodeLog, LogError, read_episode_log
from dynplan.logs.recording import check_recorded, of_world
from dynplan.logs.writer import write_episode_log
from dynplan.planning.episode import run_episode
from dynplan.planning.forward import Prediction
from dynplan.render import error_image, side_by_side, write_gif

if TYPE_CHECKING:
    from dynplan.planning.mcts import Decision


def planners() -> list[str]:
    """What a replay's planner may be: any registered technique, or "model" (the learned world model with the
    samples and futures given)."""
    return [*TECHNIQUES, LEARNED]


def prepare(log: str | os.PathLike, agent: AgentSpec, agent_speed: float) -> tuple[EpisodeLog, RoadConfig]:
    """Check a replay's inputs before running it: a learned agent's checkpoints (CheckpointError), the speed
    (ConfigError) and the log (LogError): long enough for an episode at that speed."""
    agent.check_weights()  # loads (and caches) the checkpoints, or says which are missing
    RoadConfig(agent_speed=agent_speed)  # validates the speed before the log is read
    recorded = check_recorded(of_world(read_episode_log(log), "road"))  # the world first: no other world is run
    config = RoadConfig.from_dict(recorded.config.model_dump(), agent_speed=agent_speed)
    if config.max_steps > recorded.n_frames:
        raise LogError(log, f"holds {recorded.n_frames} frames; agent speed {agent_speed:g} needs {config.max_steps}")
    return recorded, config


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


def replay(
    log: str | os.PathLike,
    agent: AgentSpec | None = None,
    agent_speed: float = 1.0,
    out: str | os.PathLike | None = None,
    gif: str | os.PathLike | None = None,
    live: LiveView | None = None,
    pace_s: float = 0.0,
) -> ReplayResult:
    """Run `agent` (default: the oracle) on the episode recorded in `log` at `agent_speed`: the planner and the
    world model draw from `agent.seed`. `out`: a replay log of the episode (the agent's track, its imagined frames
    and searches); `gif`: its picture; `live`: also publish every frame and decision there as it is planned, at
    least `pace_s` seconds apart (a viewer follows the episode)."""
    agent = agent or AgentSpec(technique="oracle")
    recorded, config = prepare(log, agent, agent_speed)
    world = recorded.world()
    planner, forward = agent.build(world, agent_speed)
    rollout_steps = agent.rollout_steps
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
            imagined_now = None if prediction is None else prediction.frames
            live.show(t, world.frames[t], world.goal[t], position, search[-1], imagined_now, step)
            shown[0] = time.perf_counter()

    if live is not None:  # the frames observed before the first decision
        for t in range(FIRST_DECISION_FRAME):
            live.show(t, world.frames[t], world.goal[t])

    result = run_episode(world, planner, forward, agent_speed, rollout_steps, on_decision=record)
    if live is not None:  # where the episode ended
        track, last = result.track, int(result.track.t[-1])
        live.show(last, world.frames[last], world.goal[last], track.position[-1], step=track.step_row(-1))
    if out is not None:
        write_episode_log(
            out, world, agent=result.track, n_frames=config.max_steps, imagined=imagined or None, search=search
        )
    if gif is not None:
        write_gif(gif, np.stack(panels), fps=8, scale=4)
    ms = np.asarray(result.decision_ms)
    timing = (round(float(np.median(ms)), 4), round(float(ms.mean()), 4))
    paths = (None if out is None else str(out), None if gif is None else str(gif))
    return ReplayResult(
        str(log), agent.technique, agent_speed, rollout_steps, result.outcome, result.steps, *timing, *paths
    )


def search_row(t: int, prediction: Prediction | None, decision: Decision) -> dict:
    """A decision as the log's /planner/search row: the root's visits, Q and prior per action, its value (Q
    averaged over the visits), the search's time and the prediction's goal at t + 1 (no `goal` where it shows none)."""
    visits = np.asarray(decision.visits, np.float64)
    value = float((visits * decision.q).sum() / visits.sum()) if visits.sum() else 0.0
    row = {
        "t": int(t),
        "action": int(decision.action),
        "visits": [int(v) for v in decision.visits],
        "q": [round(float(q), 6) for q in decision.q],
        "prior": [round(float(p), 6) for p in decision.prior],
        "value": round(value, 6),
        "search_ms": round(float(decision.search_ms), 4),
    }
    if prediction is not None and len(prediction.goal) and not np.isnan(prediction.goal[0, 0]):
        row["goal"] = {"x": float(prediction.goal[0, 1]), "y": float(prediction.goal[0, 0])}
    return row


def _gif_panel(frames: np.ndarray, t: int, position: np.ndarray, prediction: Prediction | None, k: int) -> np.ndarray:
    """Observed frame | true frame at the horizon | predicted frame at the horizon | error."""
    h = min(k, len(frames) - 1 - t) if prediction is None else len(prediction.frames)
    truth = frames[t + h]
    predicted = prediction.frames[h - 1] if prediction is not None else np.zeros_like(truth)
    return side_by_side(
        [colorize(frames[t], position), colorize(truth), colorize(predicted), error_image(truth, predicted)]
    )


def default_outputs(log: str | os.PathLike, agent: AgentSpec) -> Path:
    """Default replay log path: a `replays/` folder beside the input's folder (kept apart from recorded
    episodes, so that a folder of logs stays a folder of worlds), named for the episode and the planner."""
    log = Path(log)
    name = agent.technique
    if agent.technique == LEARNED:
        name = f"model-{agent.model}-s{agent.samples}-f{agent.futures}"
    return log.parent.parent / "replays" / f"{log.stem}.replay-{name}.mcap"
