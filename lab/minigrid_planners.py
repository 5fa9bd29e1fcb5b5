"""How well MiniGrid's planner does with each kind of future: success rate (± its standard error), deaths, steps
and decision ms over recorded rooms, for every technique of the evaluation (`dynplan.worlds.minigrid.evaluation`):
the true future, futures sampled from the balls' move rule or from the world model, stand-still, constant velocity
and random actions.

`python -m lab.minigrid_planners --first-seed 3000000 --episodes 200 [--samples 64] [--risk 1.0] [--horizon 5]
[--commit 5] [--techniques …] [--model-dir DIR] [--learned-samples S]`
(seeds 3,000,000… are the planner's validation rooms: settings are chosen there).
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from dynplan.worlds.minigrid.evaluation import TECHNIQUES, play_episode
from dynplan.worlds.minigrid.grid import MiniGridConfig, record_world
from dynplan.worlds.minigrid.imagine import MiniGridModel
from dynplan.worlds.minigrid.results import LEARNED_SAMPLES
from dynplan.worlds.minigrid.search import GridSearch


def summary(rows: list[dict]) -> dict:
    won = np.array([r["outcome"] == "goal" for r in rows], float)
    return {
        "episodes": len(rows),
        "success": round(float(won.mean()), 3),
        "se": round(float(won.std(ddof=1) / np.sqrt(len(won))) if len(won) > 1 else 0.0, 3),
        "deaths": sum(r["outcome"] == "death" for r in rows),
        "steps": round(float(np.mean([r["steps"] for r in rows if r["outcome"] == "goal"] or [0])), 1),
        "ms": round(float(np.median([r["decision_ms"] for r in rows])), 2),
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
    parser.add_argument("--model-dir", default=None, help="folder holding minigrid/{vqvae,pixelcnn}.pt")
    parser.add_argument("--learned-samples", type=int, default=None, help="a trial: learned10 samples this many")
    args = parser.parse_args(argv)
    if args.learned_samples:
        LEARNED_SAMPLES["learned10"] = args.learned_samples
    search = GridSearch(horizon=args.horizon, risk=args.risk, commit=args.commit)
    seeds = range(args.first_seed, args.first_seed + args.episodes)
    model = MiniGridModel(args.model_dir) if any(t in LEARNED_SAMPLES for t in args.techniques) else None
    out = {}
    for technique in args.techniques:
        rows = [
            play_episode(technique, record_world(MiniGridConfig(), seed), search, args.samples, model) for seed in seeds
        ]
        out[technique] = summary(rows)
        print(json.dumps({technique: out[technique]}), flush=True)
    return out


if __name__ == "__main__":
    main()
