"""Playing MiniGrid's techniques over recorded rooms into a run of the results store.

A technique is what the planner is told of the balls' next frames (`dynplan.worlds.minigrid.futures`), or `random`
(no search). Each episode's room is recorded from its seed; its sampled futures draw from a generator seeded by it,
so a row plays again to the same actions. `play_episode` plays one; `evaluate_episodes` appends each row to its run
as its episode ends; `summarise` gives each technique's success rate with its standard error.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence

import numpy as np

from dynplan.evaluation.store import Run, code_version
from dynplan.worlds.minigrid import futures
from dynplan.worlds.minigrid.agent import AGENT_START_POSE, Outcome, step
from dynplan.worlds.minigrid.grid import MiniGridConfig, MiniGridWorld, record_world
from dynplan.worlds.minigrid.results import TECHNIQUE_NAMES, encode_actions
from dynplan.worlds.minigrid.search import GridSearch, plan_grid

TECHNIQUES = TECHNIQUE_NAMES


def futures_of(technique: str, room: MiniGridWorld, t: int, search: GridSearch, samples: int, rng) -> np.ndarray:
    """What the technique tells the planner of the room's next k frames at step t, (F, k + 1, H, W)."""
    if technique == "walk":
        return futures.walk(room.frames, t, search.horizon, samples, rng)
    return getattr(futures, technique)(room.frames, t, search.horizon)


def play_episode(technique: str, room: MiniGridWorld, search: GridSearch, samples: int) -> dict:
    """One episode of the room by the technique: how it ended, its steps, median decision ms and actions."""
    if technique not in TECHNIQUES:
        raise ValueError(f"technique {technique!r} is not one of MiniGrid's: {', '.join(TECHNIQUES)}")
    rng = np.random.default_rng(room.seed)
    pose, outcome, actions, ms = AGENT_START_POSE, Outcome.RUNNING, [], []
    while outcome == Outcome.RUNNING and len(actions) < len(room.frames) - 1:
        t, start = len(actions), time.perf_counter()
        if technique == "random":
            action = int(rng.integers(0, 3))
        else:
            action = plan_grid(pose, futures_of(technique, room, t, search, samples, rng), room.goal[0], search).action
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
    run: Run, technique: str, seeds: Sequence[int], config: MiniGridConfig, search: GridSearch, samples: int
) -> list[dict]:
    """Play the rooms of `seeds` with the technique, appending each row to `run` as its episode ends."""
    rows = []
    for seed in seeds:
        played = play_episode(technique, record_world(config, seed), search, samples)
        row = {"technique": technique, "model": None, "seed": int(seed), **played, "code_version": code_version()}
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
