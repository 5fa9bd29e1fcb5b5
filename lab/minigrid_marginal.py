"""A trial: MiniGrid's planner against the balls' occupancy probabilities instead of sampled futures.

Each step's chance that a cell holds a ball is spread from the frame now by the balls' move rule, one ball at a time
and ignoring the others (each ball to its free neighbours, uniformly); a sequence's value is then computed in
expectation — survival the product over its steps of one less the chance of a ball on its cell — with no sampling
noise. `python -m lab.minigrid_marginal --first-seed 3000000 --episodes 100 [--risk 1.0]`
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from dynplan.worlds.minigrid.agent import AGENT_START_POSE, FORWARD, HEADINGS, LEFT, RIGHT, Outcome, step
from dynplan.worlds.minigrid.futures import walk
from dynplan.worlds.minigrid.grid import PIXEL_VALUES, MiniGridConfig, record_world
from dynplan.worlds.minigrid.search import PREFERENCE, distance, sequences

BALL, FLOOR, WALL, GOAL = (PIXEL_VALUES[k] for k in ("ball", "floor", "wall", "goal"))
KING = [(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1) if (dr, dc) != (0, 0)]


def occupancy(frame: np.ndarray, k: int) -> np.ndarray:
    """(k + 1, H, W): the chance of a ball on each cell at each step, from the frame now."""
    free = (frame == FLOOR) | (frame == BALL)
    out = [(frame == BALL).astype(float)]
    for _ in range(k):
        p, spread = out[-1], np.zeros_like(out[-1])
        counts = sum(np.roll(np.roll(free, -dr, 0), -dc, 1) for dr, dc in KING)  # free neighbours of each cell
        share = np.where(counts > 0, p / np.maximum(counts, 1), 0.0)
        for dr, dc in KING:
            spread += np.roll(np.roll(share, dr, 0), dc, 1) * free
        stay = np.where(counts == 0, p, 0.0)
        out.append(np.minimum(spread + stay, 1.0))
    return np.stack(out)


def plan(pose, frame, goal, k: int, risk: float, occ: np.ndarray | None = None) -> int:
    seqs = sequences(k)
    n = len(seqs)
    pos = np.tile(np.array(pose), (n, 1))
    alive, won = np.ones(n), np.zeros(n)
    occ = occupancy(frame, k) if occ is None else occ
    for t in range(k):
        action = seqs[:, t]
        forward = action == FORWARD
        target = pos[:, :2] + HEADINGS[pos[:, 2]] * forward[:, None]
        wall = forward & (frame[target[:, 0], target[:, 1]] == WALL)
        hit = occ[t + 1, target[:, 0], target[:, 1]]
        swap = forward * occ[t, target[:, 0], target[:, 1]] * occ[t + 1, pos[:, 0], pos[:, 1]]
        running = alive * (1 - won)
        survive = np.where(wall, 0.0, (1 - hit) * (1 - swap))
        at_goal = frame[target[:, 0], target[:, 1]] == GOAL
        won = won + running * survive * at_goal
        alive = alive - running * (1 - survive)
        turn = np.where(action == LEFT, (pos[:, 2] + 3) % 4, np.where(action == RIGHT, (pos[:, 2] + 1) % 4, pos[:, 2]))
        pos = np.column_stack([np.where(wall[:, None], pos[:, :2], target), turn])
    died = 1 - alive
    near = -np.minimum(distance(pos, goal) / (2.0 * frame.shape[-1]), 1.0)
    score = won * 1.0 + (alive - won) * near - died - risk * died
    values = np.array([score[seqs[:, 0] == a].max() for a in range(3)])
    return max(PREFERENCE, key=lambda a: (values[a], -PREFERENCE.index(a)))


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(prog="python -m lab.minigrid_marginal", description=__doc__)
    parser.add_argument("--first-seed", type=int, default=3_000_000)
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--risk", type=float, default=1.0)
    parser.add_argument("--horizon", type=int, default=5)
    parser.add_argument("--samples", type=int, default=0, help="estimate the chances from this many sampled futures")
    args = parser.parse_args(argv)
    rows = []
    for seed in range(args.first_seed, args.first_seed + args.episodes):
        room = record_world(MiniGridConfig(), seed)
        rng = np.random.default_rng(seed)
        pose, outcome, t, ms = AGENT_START_POSE, Outcome.RUNNING, 0, []
        while outcome == Outcome.RUNNING and t < len(room.frames) - 1:
            start = time.perf_counter()
            occ = None
            if args.samples:
                drawn = walk(room.frames, t, args.horizon, args.samples, rng)
                occ = (drawn == BALL).mean(axis=0)
            action = plan(pose, room.frames[t], room.goal[0], args.horizon, args.risk, occ)
            ms.append((time.perf_counter() - start) * 1e3)
            pose, outcome = step(pose, action, room.frames[t], room.frames[t + 1])
            t += 1
        rows.append((outcome == Outcome.GOAL, outcome == Outcome.DEATH, float(np.median(ms))))
    won = np.array([r[0] for r in rows], float)
    out = {
        "success": round(won.mean(), 3),
        "se": round(won.std(ddof=1) / np.sqrt(len(won)), 3),
        "deaths": int(sum(r[1] for r in rows)),
        "ms": round(float(np.median([r[2] for r in rows])), 2),
    }
    print(
        json.dumps({"marginal": out, "risk": args.risk, "horizon": args.horizon, "samples": args.samples}), flush=True
    )
    return out


if __name__ == "__main__":
    main()
