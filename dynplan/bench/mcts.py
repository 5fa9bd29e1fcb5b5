"""`mcts`: milliseconds per oracle decision (prediction + 100-playout search) on one core, k = 3 and k = 10."""

from __future__ import annotations

import numpy as np

from dynplan.bench.timing import pin_to_one_core
from dynplan.env.config import RoadConfig
from dynplan.env.road import generate_world
from dynplan.planning.config import MCTSConfig
from dynplan.planning.episode import run_episode
from dynplan.planning.forward import OracleModel
from dynplan.planning.mcts import MCTSPlanner

#: The authors' code (ported to Python 3, 50 episodes per case; docs/protocol.md §4), seconds → ms; not re-run here.
REFERENCE_MS = {3: 120.0, 10: 402.0}  # medians
TARGET_MS_K10 = 5.0


def bench_mcts(episodes: int = 20) -> dict[str, dict[str, float]]:
    """Play `episodes` oracle episodes (2× agent) per horizon and time every decision."""
    pin_to_one_core()
    config = RoadConfig(agent_speed=1.0)
    worlds = [generate_world(config, 2_000_000 + i) for i in range(episodes)]
    results = {}
    for k in (3, 10):
        times: list[float] = []
        for i, world in enumerate(worlds):
            planner = MCTSPlanner(MCTSConfig(rollout_steps=k, playouts=100), 1.0, config.max_steps, seed=i)
            run_episode(world, planner, OracleModel(world), 1.0, k)  # warm-up (numba compile on first call)
            times += run_episode(world, planner, OracleModel(world), 1.0, k).decision_ms
        median = float(np.median(times))
        results[f"oracle_k{k}"] = {
            "median_ms": round(median, 3),
            "mean_ms": round(float(np.mean(times)), 3),
            "decisions": len(times),
            "reference_median_ms": REFERENCE_MS[k],
            "speedup_vs_reference": round(REFERENCE_MS[k] / median),
        }
    results["oracle_k10"]["target_ms"] = TARGET_MS_K10
    return results
