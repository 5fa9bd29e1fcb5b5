"""A trial: the walk's sampled futures told to the planner as chances, as the learned technique's are.

Each of S futures is sampled from the balls' true move rule; at each of its steps the planner is told each cell's
chance of a ball given that future's room the step before (the rule's one-step spread, `lab.minigrid_marginal`'s
`occupancy`), not the 0/1 of the sampled room — the same estimate the learned technique makes from its prior's
softmax. Set beside `learnedS` on the same rooms, it separates what the estimate costs from what the model costs.
`python -m lab.minigrid_chances --first-seed 3000000 --episodes 100 --samples 10 [--risk 1.0] [--commit 5]
[--horizon 5]`
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from dynplan.worlds.minigrid.agent import AGENT_START_POSE, Outcome, step
from dynplan.worlds.minigrid.futures import walk
from dynplan.worlds.minigrid.grid import MiniGridConfig, record_world
from dynplan.worlds.minigrid.search import BALL, GridSearch, layout_of, plan_chances
from lab.minigrid_marginal import occupancy
from lab.minigrid_planners import summary


def chances(frames: np.ndarray, t: int, k: int, samples: int, rng: np.random.Generator) -> np.ndarray:
    """(S, k + 1, H, W): each sampled future's chance of a ball in each cell, given its room the step before."""
    drawn = walk(frames, t, k, samples, rng)
    out = np.empty(drawn.shape, np.float32)
    out[:, 0] = drawn[:, 0] == BALL
    for s in range(samples):
        for j in range(1, k + 1):
            out[s, j] = occupancy(drawn[s, j - 1], 1)[1]
    return out


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(prog="python -m lab.minigrid_chances", description=__doc__)
    parser.add_argument("--first-seed", type=int, default=3_000_000)
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--samples", type=int, default=10)
    parser.add_argument("--risk", type=float, default=1.0)
    parser.add_argument("--commit", type=int, default=5)
    parser.add_argument("--horizon", type=int, default=5)
    args = parser.parse_args(argv)
    search, rows = GridSearch(horizon=args.horizon, risk=args.risk, commit=min(args.commit, args.horizon)), []
    for seed in range(args.first_seed, args.first_seed + args.episodes):
        room, rng = record_world(MiniGridConfig(), seed), np.random.default_rng(seed)
        pose, outcome, t, ms = AGENT_START_POSE, Outcome.RUNNING, 0, []
        while outcome == Outcome.RUNNING and t < len(room.frames) - 1:
            start = time.perf_counter()
            balls = chances(room.frames, t, search.horizon, args.samples, rng)
            action = plan_chances(pose, layout_of(room.frames[t]), balls, room.goal[0], search).action
            ms.append((time.perf_counter() - start) * 1e3)
            pose, outcome = step(pose, action, room.frames[t], room.frames[t + 1])
            t += 1
        ended = Outcome.TIMEOUT if outcome == Outcome.RUNNING else outcome
        rows.append({"outcome": ended.name.lower(), "steps": t, "decision_ms": float(np.median(ms))})
    out = summary(rows)
    settings = {"samples": args.samples, "risk": args.risk, "commit": search.commit, "horizon": args.horizon}
    print(json.dumps({"walk_chances": out, **settings}), flush=True)
    return out


if __name__ == "__main__":
    main()
