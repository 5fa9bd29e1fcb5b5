"""A trial: MiniGrid's search with a value past its horizon — the balls' expected number in the 3 × 3 cells around
where a sequence ends, weighed by `clearance` — against the true rule's chances from sampled futures
(`lab.minigrid_chances`). A sequence that ends hemmed in is worth less than one that ends in the open, which the
horizon alone does not see. `python -m lab.minigrid_clearance --episodes 100 --samples 10 --clearance 0.1`
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from dynplan.worlds.minigrid.agent import AGENT_START_POSE, Outcome, roll_chances, step
from dynplan.worlds.minigrid.grid import MiniGridConfig, record_world
from dynplan.worlds.minigrid.search import BALL, FLOOR, PREFERENCE, GridSearch, distance, sequences
from lab.minigrid_chances import chances
from lab.minigrid_planners import summary


def crowding(balls: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """(A, F): each future's expected balls in the 3 × 3 cells around each sequence's last pose, at its last step."""
    last = balls[:, -1]
    padded = np.pad(last, ((0, 0), (1, 1), (1, 1)))
    around = sum(padded[:, 1 + dr : 1 + dr + last.shape[1], 1 + dc : 1 + dc + last.shape[2]]
                 for dr in (-1, 0, 1) for dc in (-1, 0, 1))  # fmt: skip
    futures = np.arange(balls.shape[0])[None, :]
    return around[futures, poses[..., 0], poses[..., 1]]


def plan(pose, layout, balls, goal, search: GridSearch, clearance: float) -> int:
    """`plan_chances` committed to whole sequences, its value less `clearance` × the crowding where each ends."""
    seqs = sequences(search.horizon)
    rolled = roll_chances(pose, seqs, layout, balls)
    near = -np.minimum(distance(rolled.poses, goal) / (2.0 * layout.shape[-1]), 1.0)
    running = 1.0 - rolled.won - rolled.died
    value = rolled.won - rolled.died + running * (near - clearance * crowding(balls, rolled.poses))
    score = value.mean(axis=1) - search.risk * rolled.died.mean(axis=1)
    values = np.array([score[seqs[:, 0] == a].max() for a in range(3)])
    return max(PREFERENCE, key=lambda a: (values[a], -PREFERENCE.index(a)))


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(prog="python -m lab.minigrid_clearance", description=__doc__)
    parser.add_argument("--first-seed", type=int, default=3_000_000)
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--samples", type=int, default=10)
    parser.add_argument("--clearance", type=float, default=0.1)
    args = parser.parse_args(argv)
    search, rows = GridSearch(), []
    for seed in range(args.first_seed, args.first_seed + args.episodes):
        room, rng = record_world(MiniGridConfig(), seed), np.random.default_rng(seed)
        pose, outcome, t, ms = AGENT_START_POSE, Outcome.RUNNING, 0, []
        while outcome == Outcome.RUNNING and t < len(room.frames) - 1:
            start = time.perf_counter()
            layout = np.where(room.frames[t] == BALL, FLOOR, room.frames[t])
            balls = chances(room.frames, t, search.horizon, args.samples, rng)
            action = plan(pose, layout, balls, room.goal[0], search, args.clearance)
            ms.append((time.perf_counter() - start) * 1e3)
            pose, outcome = step(pose, action, room.frames[t], room.frames[t + 1])
            t += 1
        ended = Outcome.TIMEOUT if outcome == Outcome.RUNNING else outcome
        rows.append({"outcome": ended.name.lower(), "steps": t, "decision_ms": float(np.median(ms))})
    out = summary(rows)
    print(json.dumps({"clearance": args.clearance, "samples": args.samples, **out}), flush=True)
    return out


if __name__ == "__main__":
    main()
