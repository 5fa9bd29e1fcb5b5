"""How well MiniGrid's planner does with each kind of future: success rate (± its standard error), deaths, steps
and decision ms over recorded rooms, for the true future, stand-still, constant velocity, futures sampled from the
balls' move rule, and random actions.

`python -m lab.minigrid_planners --first-seed 3000000 --episodes 200 [--samples 64] [--risk 1.0] [--horizon 5]
[--commit 5]`
(seeds 3,000,000… are the planner's validation rooms: settings are chosen there).
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from dynplan.worlds.minigrid import futures
from dynplan.worlds.minigrid.agent import AGENT_START_POSE, Outcome, step
from dynplan.worlds.minigrid.grid import MiniGridConfig, record_world
from dynplan.worlds.minigrid.search import GridSearch, plan_grid

TECHNIQUES = ("oracle", "stand_still", "constant_velocity", "walk", "random")


def play(technique: str, seed: int, search: GridSearch, samples: int) -> dict:
    """One room played by the technique: its outcome, steps and median decision ms."""
    room = record_world(MiniGridConfig(), seed)
    rng = np.random.default_rng(seed)
    pose, outcome, t, ms = AGENT_START_POSE, Outcome.RUNNING, 0, []
    while outcome == Outcome.RUNNING and t < len(room.frames) - 1:
        start = time.perf_counter()
        if technique == "random":
            action = int(rng.integers(0, 3))
        else:
            seen = (
                futures.walk(room.frames, t, search.horizon, samples, rng)
                if technique == "walk"
                else getattr(futures, technique)(room.frames, t, search.horizon)
            )
            action = plan_grid(pose, seen, room.goal[0], search).action
        ms.append((time.perf_counter() - start) * 1e3)
        pose, outcome = step(pose, action, room.frames[t], room.frames[t + 1])
        t += 1
    outcome = Outcome.TIMEOUT if outcome == Outcome.RUNNING else outcome
    return {
        "technique": technique,
        "seed": seed,
        "outcome": outcome.name.lower(),
        "steps": t,
        "ms": float(np.median(ms)),
    }


def summary(rows: list[dict]) -> dict:
    won = np.array([r["outcome"] == "goal" for r in rows], float)
    return {
        "episodes": len(rows),
        "success": round(float(won.mean()), 3),
        "se": round(float(won.std(ddof=1) / np.sqrt(len(won))) if len(won) > 1 else 0.0, 3),
        "deaths": sum(r["outcome"] == "death" for r in rows),
        "steps": round(float(np.mean([r["steps"] for r in rows if r["outcome"] == "goal"] or [0])), 1),
        "ms": round(float(np.median([r["ms"] for r in rows])), 2),
    }


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(prog="python -m lab.minigrid_planners", description=__doc__)
    parser.add_argument("--first-seed", type=int, default=3_000_000)
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--samples", type=int, default=64)
    parser.add_argument("--risk", type=float, default=1.0)
    parser.add_argument("--horizon", type=int, default=5)
    parser.add_argument("--commit", type=int, default=5)
    parser.add_argument("--techniques", nargs="+", default=list(TECHNIQUES), choices=TECHNIQUES)
    args = parser.parse_args(argv)
    search = GridSearch(horizon=args.horizon, risk=args.risk, commit=args.commit)
    seeds = range(args.first_seed, args.first_seed + args.episodes)
    out = {}
    for technique in args.techniques:
        rows = [play(technique, seed, search, args.samples) for seed in seeds]
        out[technique] = summary(rows)
        print(json.dumps({technique: out[technique]}), flush=True)
    return out


if __name__ == "__main__":
    main()
