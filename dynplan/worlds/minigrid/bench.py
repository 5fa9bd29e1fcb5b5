"""`minigrid`: milliseconds per MiniGrid decision — the learned agent's (its world model's futures and the search)
with 10, 5 and 1 samples on every core and on one, beside the distribution-aware planner (64 futures of the true
ball rule) and the search alone (10 futures of chances), in the same run.

Each case decides at the first `STEPS` steps of `ROOMS` validation rooms (seeds 3,000,000…), the agent walking the
way the true future's planner walks (so every case decides in the same places); the committed world model. The
figures are medians; `load_before` is the machine's 1-minute load average when the benchmark began (0 to 0.3 on an
idle machine), so a reader knows whether other work shared the cores.
"""

from __future__ import annotations

import os
import time

import numpy as np
import torch

from dynplan.worlds.minigrid import futures
from dynplan.worlds.minigrid.agent import AGENT_START_POSE, Outcome, step
from dynplan.worlds.minigrid.evaluation import Player, decide
from dynplan.worlds.minigrid.grid import MiniGridConfig, record_world
from dynplan.worlds.minigrid.imagine import MiniGridModel
from dynplan.worlds.minigrid.search import GridSearch, layout_of, plan_chances, plan_grid

#: The acceptance target of a learned decision on 2 cores.
TARGET_MS = 50.0
ROOMS, STEPS, FIRST_SEED = 5, 20, 3_000_000


def _places() -> list[tuple]:
    """(room, t, pose) of every decision timed: the true future's planner's path through each room's first steps."""
    places, search = [], GridSearch()
    for seed in range(FIRST_SEED, FIRST_SEED + ROOMS):
        room, pose = record_world(MiniGridConfig(), seed), AGENT_START_POSE
        for t in range(STEPS):
            places.append((room, t, pose))
            action = plan_grid(pose, futures.oracle(room.frames, t, search.horizon), room.goal[0], search).action
            pose, outcome = step(pose, action, room.frames[t], room.frames[t + 1])
            if outcome != Outcome.RUNNING:
                break
    return places


def _timed(decide, places: list[tuple]) -> dict[str, float]:
    times = []
    for room, t, pose in places:
        start = time.perf_counter()
        decide(room, t, pose)
        times.append((time.perf_counter() - start) * 1e3)
    return {"median_ms": round(float(np.median(times)), 3), "decisions": len(times)}


def bench_minigrid() -> dict[str, dict[str, float]]:
    """Time each case's decisions at the same places; the learned ones against `TARGET_MS` and the walk's."""
    load, threads = os.getloadavg()[0], torch.get_num_threads()
    player, places = Player(GridSearch(), 64, np.random.default_rng(0), MiniGridModel()), _places()

    def technique(name: str):
        return lambda room, t, pose: decide(name, room, t, pose, player)

    def search_only(room, t, pose) -> int:
        balls = np.full((10, player.search.horizon + 1, *room.frames.shape[1:]), 0.1, np.float32)
        return plan_chances(pose, layout_of(room.frames[t]), balls, room.goal[0], player.search).action

    technique("learned10")(*places[0])  # compiles the generation kernel and loads the weights before any timing
    results = {"walk64": _timed(technique("walk"), places)}
    for count in dict.fromkeys((1, threads)):  # one thread, then every core's (once, on one core)
        torch.set_num_threads(count)
        for samples in (10, 5, 1):
            case = f"learned{samples}" + ("_1thread" if count == 1 and threads > 1 else "")
            timed = _timed(technique(f"learned{samples}"), places)
            results[case] = {**timed, "threads": count, "target_ms": TARGET_MS}
    torch.set_num_threads(threads)
    results["search_only"] = _timed(search_only, places)
    for samples in (10, 5, 1):
        results[f"learned{samples}"]["ratio_walk64"] = round(
            results[f"learned{samples}"]["median_ms"] / results["walk64"]["median_ms"], 2
        )
    results["machine"] = {"load_before": round(load, 2), "threads": threads}
    return results
