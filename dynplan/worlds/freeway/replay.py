"""A Freeway episode replayed into a log Foxglove shows: the mode's recorded lanes, the chicken entering at its NOOP
start, its pose, actions, rewards and view at each step, and the lanes the planner searched at each decision.

The replay log holds the mode's whole recording (`/world/frame` from the game's start) so that its world is the
recorded log's; the chicken's track starts at frame n, the episode's NOOP start. Its pose is the middle of the
chicken's sprite (`chicken_row`, `CHICKEN_COLUMN`: below row 0 on the bottom sidewalk); a step's reward is 1 at a
crossing, and the last step's outcome is "timeout" (the game's end). A GIF may show the replay's first steps: the
lanes now with the chicken beside the true lanes k steps on, the lanes the planner searched for then (a learned
agent's imagined ones) and their error panel.
"""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

import numpy as np

from dynplan.env.colors import colorize
from dynplan.logs.format import AgentTrack
from dynplan.logs.reader import EpisodeLog, LogError
from dynplan.logs.recording import read_world_recording
from dynplan.logs.writer import write_episode_log
from dynplan.planning.forward import ForwardModel
from dynplan.render import error_image, side_by_side, write_gif
from dynplan.worlds.freeway.evaluation import FreewayResult, Turn, play_turns, result_of
from dynplan.worlds.freeway.game import CHICKEN_COLUMN, Chicken, FreewayEpisode, chicken_mask, chicken_row
from dynplan.worlds.freeway.search import ChickenSearch

#: Steps of a replay its GIF shows, from the episode's start (the whole game would be minutes of GIF).
GIF_STEPS = 150


def replayable(log: str | os.PathLike) -> EpisodeLog:
    """`log`, read and checked: a whole Freeway mode's recording, as `flows.collect` writes it; else a LogError."""
    wanted = "a Freeway replay plays a Freeway mode's recording (flows.collect --world freeway)"
    recorded = read_world_recording(log, "freeway", wanted)
    if recorded.n_frames < recorded.config.max_steps:
        raise LogError(
            log,
            f"holds {recorded.n_frames} frames of the game's {recorded.config.max_steps}; record the "
            "whole mode (flows.collect --world freeway without a frame limit)",
        )
    return recorded


def default_replay_path(log: str | os.PathLike, technique: str, noop_start: int) -> Path:
    """Where a replay of `log` goes by default: beside the log's folder, in `replays/`."""
    log = Path(log)
    return log.parent.parent / "replays" / f"{log.stem}.replay-{technique}-noop{noop_start}.mcap"


def chicken_position(chicken: Chicken) -> np.ndarray:
    """The chicken's (row, column) in the lane frame."""
    return np.array([chicken_row(chicken.y), CHICKEN_COLUMN])


def track(turns: list[Turn], noop_start: int) -> AgentTrack:
    """The chicken's track through the turns, the first pose at frame `noop_start`; its last outcome is "timeout"
    where the game ended (2,048 steps), "running" where the turns stop before."""
    chickens = [turns[0].chicken] + [turn.step.chicken for turn in turns]
    outcomes = ("running",) * (len(turns) - 1) + ("timeout" if turns[-1].step.done else "running",)
    positions = np.stack([chicken_position(c) for c in chickens])
    return AgentTrack(
        t=noop_start + np.arange(len(chickens)),
        position=positions,
        action=np.array([turn.action for turn in turns]),
        reward=np.array([turn.step.reward for turn in turns]),
        outcome=outcomes,
    )


def replay_gif(
    path: str | os.PathLike, turns: list[Turn], frames: np.ndarray, noop_start: int, steps: int = GIF_STEPS
) -> Path:
    """A GIF of the first `steps` turns (a planner's) of an episode of the recording `frames` starting at
    `noop_start`: the lanes now with the chicken | the true lanes k steps on | those the planner searched | error."""
    panels = []
    for i, turn in enumerate(turns[:steps]):
        if turn.frames is None:
            raise ValueError("a replay's GIF shows the lanes a planner searched; this technique does not plan")
        t, k = noop_start + i, len(turn.frames) - 1
        truth, searched = frames[min(t + k, len(frames) - 1)], turn.frames[k]
        now = colorize(frames[t])
        now[np.flip(chicken_mask(frames[t].shape, turn.chicken.y), axis=0)] = 255  # the chicken in white
        panels.append(side_by_side([now, colorize(truth), colorize(searched), error_image(truth, searched, "freeway")]))
    return write_gif(path, panels, fps=15, scale=1)


def replay_freeway(
    log: str | os.PathLike,
    technique: str,
    noop_start: int,
    search: ChickenSearch,
    out: str | os.PathLike,
    model: ForwardModel | None = None,
    gif: str | os.PathLike | None = None,
) -> FreewayResult:
    """Play the episode of `log`'s mode with NOOP start `noop_start` by `technique` (with `model` when learned) and
    write its replay to `out` (and, with `gif`, its first steps' GIF there)."""
    recorded = replayable(log)
    episode = FreewayEpisode(mode=recorded.seed, noop_start=noop_start)
    turns = list(play_turns(technique, episode, search, model=model))
    if gif is not None:
        replay_gif(gif, turns, recorded.world().frames, noop_start)
    imagined = {noop_start + i: turn.frames[1:] for i, turn in enumerate(turns) if turn.frames is not None}
    write_episode_log(out, recorded.world(), agent=track(turns, noop_start), imagined=imagined or None)
    return replace(result_of(turns, technique, episode, search.horizon), episode=0)
