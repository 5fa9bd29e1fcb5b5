"""Trials on how the learned MiniGrid technique draws its futures, and a look at what the prior's futures hold.

`plan`: learned10 on validation rooms with its futures drawn at `--temperature T` (the prior's softmax at T, by
`dynplan.models.chain.SAMPLED`), or drawn `--conserve X` times over and the first 10 kept whose rooms hold as many
balls at every step as the room now (the fewest miscounted where fewer do).
`look`: at steps 4, 14, 24 and 34 of `--rooms` validation rooms, the share of the prior's sampled rooms that hold
another count of balls than the room now, and the log loss (nats a room, summed over cells) of the true future
under each cell's chance of a ball: the prior's chances averaged over S futures, the rule's one-step chances over S
walk futures (`lab.minigrid_chances`) and the rule's marginal from 2,000 walk futures (the floor).

    python -m lab.minigrid_draws plan --temperature 0.8 --first-seed 3000000 --episodes 100
    python -m lab.minigrid_draws plan --conserve 2 --first-seed 3000000 --episodes 100
    python -m lab.minigrid_draws look --samples 10 100 --rooms 30
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import torch

import dynplan.models.chain as chain_module
from dynplan.worlds.minigrid import futures
from dynplan.worlds.minigrid.evaluation import play_episode
from dynplan.worlds.minigrid.futures import Imagined
from dynplan.worlds.minigrid.grid import MiniGridConfig, record_world
from dynplan.worlds.minigrid.imagine import BALL, MiniGridModel
from dynplan.worlds.minigrid.search import GridSearch
from lab.minigrid_chances import chances as rule_chances
from lab.minigrid_planners import summary

K, STEPS, EPS = 5, (4, 14, 24, 34), 1e-4


class Conserving(MiniGridModel):
    """The committed world model whose futures are drawn `extra` times over, the first S that keep the ball count."""

    def __init__(self, extra: float):
        super().__init__()
        self.extra = extra

    def imagine(self, seen: np.ndarray, k: int, samples: int) -> Imagined:
        drawn = super().imagine(seen, k, round(samples * self.extra))
        counts = (drawn.rooms[:, 1:] == BALL).sum((2, 3))
        off = np.abs(counts - int((seen[-1] == BALL).sum())).sum(1)
        keep = np.argsort(off, kind="stable")[:samples]
        return Imagined(drawn.rooms[keep], drawn.balls[keep])


def plan(args: argparse.Namespace) -> dict:
    chain_module.SAMPLED = args.temperature
    model = Conserving(args.conserve) if args.conserve else MiniGridModel()
    rooms = range(args.first_seed, args.first_seed + args.episodes)
    rows = [play_episode("learned10", record_world(MiniGridConfig(), s), GridSearch(), 64, model) for s in rooms]
    return {"temperature": args.temperature, "conserve": args.conserve, **summary(rows)}


def _log_loss(actual: np.ndarray, chance: np.ndarray) -> np.ndarray:
    p = np.clip(chance, EPS, 1 - EPS)
    return -(actual * np.log(p) + (1 - actual) * np.log(1 - p)).sum((1, 2))


def look(args: argparse.Namespace) -> dict:
    model, rng, losses, miscounted = MiniGridModel(), np.random.default_rng(0), {}, []
    for seed in range(3_000_000, 3_000_000 + args.rooms):
        room = record_world(MiniGridConfig(), seed)
        for t in STEPS:
            actual = (room.frames[t + 1 : t + 1 + K] == BALL).astype(float)
            floor = (futures.walk(room.frames, t, K, 2000, rng) == BALL).mean(0)[1:]
            losses.setdefault("rule, 2000 walk futures", []).append(_log_loss(actual, floor))
            for s in args.samples:
                imagined = model.imagine(room.frames[: t + 1], K, s)
                losses.setdefault(f"prior, {s}", []).append(_log_loss(actual, imagined.balls.mean(0)[1:]))
                rule = rule_chances(room.frames, t, K, s, rng).mean(0)[1:]
                losses.setdefault(f"rule, {s}", []).append(_log_loss(actual, rule))
                counts = (imagined.rooms[:, 1:] == BALL).sum((2, 3))
                miscounted.append(counts != (room.frames[t] == BALL).sum())
    out = {name: np.mean(v, 0).round(2).tolist() for name, v in losses.items()}
    return {"log loss, k = 1…5": out, "miscounted, k = 1…5": np.concatenate(miscounted).mean(0).round(3).tolist()}


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(prog="python -m lab.minigrid_draws", description=__doc__)
    parser.add_argument("what", choices=("plan", "look"))
    parser.add_argument("--temperature", type=float, default=1.0)
    parser.add_argument("--conserve", type=float, default=0.0)
    parser.add_argument("--first-seed", type=int, default=3_000_000)
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--samples", type=int, nargs="+", default=[10, 100])
    parser.add_argument("--rooms", type=int, default=30)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    out = plan(args) if args.what == "plan" else look(args)
    print(json.dumps(out), flush=True)
    return out


if __name__ == "__main__":
    main()
