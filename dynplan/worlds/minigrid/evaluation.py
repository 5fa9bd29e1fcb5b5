"""Playing MiniGrid's techniques over recorded rooms into a run of the results store.

A technique is what the planner is told of the balls' next frames (`dynplan.worlds.minigrid.futures`; `learnedS`: S
futures the world model samples, `imagine`), or `random` (no search). Each episode's room is recorded from its
seed; the walk's futures draw from a generator seeded by it, the world model's from streams seeded by what it saw,
so a row plays again to the same actions. `play_episode` plays one; `evaluate_episodes` appends each row to its run
as its episode ends; `summarise` gives each technique's success rate with its standard error.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from dynplan.evaluation.store import Run, code_version
from dynplan.worlds.minigrid import futures
from dynplan.worlds.minigrid.agent import AGENT_START_POSE, Outcome, Pose, step
from dynplan.worlds.minigrid.futures import Imagined
from dynplan.worlds.minigrid.grid import MiniGridConfig, MiniGridWorld, record_world
from dynplan.worlds.minigrid.models import NAME
from dynplan.worlds.minigrid.results import LEARNED_SAMPLES, RUNS, TECHNIQUE_NAMES, encode_actions
from dynplan.worlds.minigrid.search import BALL, GridSearch, layout_of, plan_chances

TECHNIQUES = TECHNIQUE_NAMES

if TYPE_CHECKING:  # the learned model needs torch: built by the command that plays with it
    from dynplan.worlds.minigrid.imagine import MiniGridModel


class Player(NamedTuple):
    """What plays an episode besides its technique: the search, the walk's samples, the episode's random numbers
    and the world model (learned techniques)."""

    search: GridSearch
    samples: int
    rng: np.random.Generator
    model: MiniGridModel | None


def futures_of(technique: str, room: MiniGridWorld, t: int, search: GridSearch, samples: int, rng) -> np.ndarray:
    """What the technique tells the planner of the room's next k frames at step t, (F, k + 1, H, W)."""
    if technique == "walk":
        return futures.walk(room.frames, t, search.horizon, samples, rng)
    return getattr(futures, technique)(room.frames, t, search.horizon)


def belief(technique: str, room: MiniGridWorld, t: int, player: Player) -> Imagined:
    """What the technique tells the planner at step t of the next k rooms: its futures' rooms and each cell's chance
    of a ball in them (a learned technique's from the world model; another's the 0/1 of its rooms)."""
    if technique in LEARNED_SAMPLES:
        return player.model.imagine(room.frames[: t + 1], player.search.horizon, LEARNED_SAMPLES[technique])
    rooms = futures_of(technique, room, t, player.search, player.samples, player.rng)
    return Imagined(rooms, (rooms == BALL).astype(np.float32))


def decide(technique: str, room: MiniGridWorld, t: int, pose: Pose, player: Player) -> int:
    """The technique's action at step t from `pose`: planned against its `belief`, or random."""
    if technique == "random":
        return int(player.rng.integers(0, 3))
    balls = belief(technique, room, t, player).balls
    return plan_chances(pose, layout_of(room.frames[t]), balls, room.goal[0], player.search).action


def play_episode(
    technique: str, room: MiniGridWorld, search: GridSearch, samples: int, model: MiniGridModel | None = None
) -> dict:
    """One episode of the room by the technique: how it ended, its steps, median decision ms and actions. A learned
    technique plans with `model` (a `MiniGridModel`)."""
    if technique not in TECHNIQUES:
        raise ValueError(f"technique {technique!r} is not one of MiniGrid's: {', '.join(TECHNIQUES)}")
    if technique in LEARNED_SAMPLES and model is None:
        raise ValueError(f"technique {technique!r} plans with a world model; none was given")
    player = Player(search, samples, np.random.default_rng(room.seed), model)
    pose, outcome, actions, ms = AGENT_START_POSE, Outcome.RUNNING, [], []
    while outcome == Outcome.RUNNING and len(actions) < len(room.frames) - 1:
        t, start = len(actions), time.perf_counter()
        action = decide(technique, room, t, pose, player)
        ms.append((time.perf_counter() - start) * 1e3)
        pose, outcome = step(pose, action, room.frames[t], room.frames[t + 1])
        actions.append(action)
    ended = Outcome.TIMEOUT if outcome == Outcome.RUNNING else outcome
    return {
        "outcome": ended.name.lower(),
        "steps": len(actions),
        "decision_ms": round(float(np.median(ms)), 4),
        "actions": encode_actions(actions),
    }


def evaluate_episodes(
    run: Run, technique: str, seeds: Sequence[int], config: MiniGridConfig, player: Player
) -> list[dict]:
    """Play the rooms of `seeds` with the technique, appending each row to `run` as its episode ends (a learned
    row names its world model and the SHA-256 the run's manifest records of its weights)."""
    rows = []
    learned = technique in LEARNED_SAMPLES
    model = {"model": NAME if learned else None}
    provenance = RUNS.expected(run.manifest(), model) if learned else {}
    for seed in seeds:
        played = play_episode(technique, record_world(config, seed), player.search, player.samples, player.model)
        row = {"technique": technique, **model, "seed": int(seed), **played, "code_version": code_version()}
        row.update(provenance)
        run.append(row)
        rows.append(row)
    return rows


def summarise(rows: Sequence[Mapping]) -> list[dict]:
    """Each technique's episodes, success rate and its standard error, deaths, mean steps to the goal and median
    decision ms, in `TECHNIQUES` order."""
    out = []
    for technique in TECHNIQUES:
        mine = [r for r in rows if r["technique"] == technique]
        if not mine:
            continue
        won = np.array([r["outcome"] == "goal" for r in mine], float)
        se = float(won.std(ddof=1) / np.sqrt(len(won))) if len(won) > 1 else 0.0
        to_goal = [r["steps"] for r in mine if r["outcome"] == "goal"]
        out.append(
            {
                "technique": technique,
                "episodes": len(mine),
                "success": round(float(won.mean()), 3),
                "se": round(se, 3),
                "deaths": sum(r["outcome"] == "death" for r in mine),
                "steps": round(float(np.mean(to_goal)), 1) if to_goal else None,
                "decision_ms": round(float(np.median([r["decision_ms"] for r in mine])), 3),
            }
        )
    return out
