"""A trial: MiniGrid's planner that knows it will see the balls near it move before its second action.

The product's search judges each whole sequence against all futures (open loop: it cannot dodge what it will see).
Here, after each first action, the futures are split by what the agent would see after that step — the balls within
`radius` cells (a king's move count) of where it stands — and within each group the agent picks the continuation
best for that group's futures. Radius −1 is the product's open-loop search; a large radius lets each future pick
its own continuation (hindsight, over-optimistic).

`python -m lab.minigrid_react --first-seed 3000000 --episodes 100 --technique walk --radius 1`
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from dynplan.worlds.minigrid import evaluation
from dynplan.worlds.minigrid.agent import AGENT_START_POSE, FORWARD, HEADINGS, WALL, Outcome, Pose, roll_chances, step
from dynplan.worlds.minigrid.grid import MiniGridConfig, record_world
from dynplan.worlds.minigrid.imagine import MiniGridModel
from dynplan.worlds.minigrid.results import LEARNED_SAMPLES
from dynplan.worlds.minigrid.search import BALL, PREFERENCE, GridSearch, distance, layout_of, sequences


def _keys(rooms: np.ndarray, cell: np.ndarray, radius: int) -> np.ndarray:
    """Each future's balls at step 1 within `radius` of `cell`, as one integer key per future."""
    if radius < 0:
        return np.zeros(len(rooms), np.int64)
    h, w = rooms.shape[-2:]
    r0, r1 = max(cell[0] - radius, 0), min(cell[0] + radius + 1, h)
    c0, c1 = max(cell[1] - radius, 0), min(cell[1] + radius + 1, w)
    patch = (rooms[:, 1, r0:r1, c0:c1] == BALL).reshape(len(rooms), -1)
    _, keys = np.unique(patch, axis=0, return_inverse=True)
    return keys.ravel()


RATE = [0.0]


def plan_react(pose: Pose, rooms: np.ndarray, balls: np.ndarray, goal: np.ndarray, search: GridSearch, radius: int):
    layout = layout_of(rooms[0, 0])
    k = min(search.horizon, balls.shape[1] - 1)
    seqs = sequences(k)
    rolled = roll_chances(pose, seqs, layout, balls[:, : k + 1])
    if RATE[0] > 0:  # the chance of winning: beyond the horizon each step to the goal survives with exp(-rate)
        score = rolled.won + (1.0 - rolled.won - rolled.died) * np.exp(-RATE[0] * distance(rolled.poses, goal))
    else:
        near = -np.minimum(distance(rolled.poses, goal) / (2.0 * layout.shape[-1]), 1.0)
        value = rolled.won - rolled.died + (1.0 - rolled.won - rolled.died) * near
        score = value - search.risk * rolled.died
    values = np.full(3, -np.inf)
    for first in range(3):
        members = np.flatnonzero(seqs[:, 0] == first)
        at = np.array(pose[:2])
        if first == FORWARD:
            ahead = at + HEADINGS[pose[2]]
            at = at if layout[ahead[0], ahead[1]] == WALL else ahead
        keys = _keys(rooms, at, radius)
        total = 0.0
        for key in np.unique(keys):
            group = np.flatnonzero(keys == key)
            total += score[np.ix_(members, group)].sum(axis=1).max()
        values[first] = total / len(rooms)
    return max(PREFERENCE, key=lambda a: (values[a], -PREFERENCE.index(a)))


def play(technique: str, seed: int, search: GridSearch, radius: int, model) -> str:
    room = record_world(MiniGridConfig(), seed)
    player = evaluation.Player(search, 64, np.random.default_rng(seed), model)
    pose, outcome, t = AGENT_START_POSE, Outcome.RUNNING, 0
    while outcome == Outcome.RUNNING and t < len(room.frames) - 1:
        imagined = evaluation.belief(technique, room, t, player)
        action = plan_react(pose, imagined.rooms, imagined.balls, room.goal[0], search, radius)
        pose, outcome = step(pose, action, room.frames[t], room.frames[t + 1])
        t += 1
    return ("timeout" if outcome == Outcome.RUNNING else outcome.name.lower()), t


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m lab.minigrid_react", description=__doc__)
    parser.add_argument("--first-seed", type=int, default=3_000_000)
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--technique", default="walk")
    parser.add_argument("--radius", type=int, default=1)
    parser.add_argument("--risk", type=float, default=1.0)
    parser.add_argument("--horizon", type=int, default=5)
    parser.add_argument("--model-dir", default=None, help="folder holding minigrid/{vqvae,pixelcnn}.pt")
    parser.add_argument("--rate", type=float, default=0.0, help="> 0: value = chance of winning, at this rate")
    args = parser.parse_args(argv)
    RATE[0] = args.rate
    model = MiniGridModel(args.model_dir) if args.technique in LEARNED_SAMPLES else None
    search = GridSearch(horizon=args.horizon, risk=args.risk)
    ends = [
        play(args.technique, s, search, args.radius, model)
        for s in range(args.first_seed, args.first_seed + args.episodes)
    ]
    outcomes = [e[0] for e in ends]
    won = np.array([o == "goal" for o in outcomes], float)
    print(
        json.dumps(
            {
                "technique": args.technique,
                "radius": args.radius,
                "risk": args.risk,
                "rate": args.rate,
                "model_dir": args.model_dir,
                "episodes": len(won),
                "success": round(won.mean(), 3),
                "se": round(won.std(ddof=1) / np.sqrt(len(won)), 3),
                "deaths": outcomes.count("death"),
                "timeouts": outcomes.count("timeout"),
            }
        ),
        flush=True,
    )


if __name__ == "__main__":
    main()
