"""How the goal prior's weights change the oracle agent: `python -m lab.prior [--episodes 100]`.

Plays the 1× oracle at k = 3 on the evaluation episodes with the paper's weights (docs/protocol.md §3:
4, 3, 2, 2, 1, 1, 1, 1) and with the flatter ones in the authors' stored code (2.5, 2.5, 2, 2, 1, 1, 1, 1),
same planner seeds as Table 1.
"""

from __future__ import annotations

import json

import numpy as np

from dynplan.cli import CommandParser, run_command
from dynplan.env.config import RoadConfig
from dynplan.env.road import generate_world
from dynplan.evaluation.cases import EVAL_SEED_START, Case
from dynplan.planning.config import PAPER_PRIOR, MCTSConfig
from dynplan.planning.episode import run_episode
from dynplan.planning.forward import OracleModel
from dynplan.planning.mcts import MCTSPlanner

FLAT_PRIOR = (2.5, 2.5, 2.0, 2.0, 1.0, 1.0, 1.0, 1.0)


def oracle_with_prior(weights: tuple[float, ...], episodes: int, agent_speed: float = 0.5, k: int = 3) -> dict:
    """G / T / D and steps (mean ± std over the not-died) of the oracle agent with prior `weights`."""
    max_steps = RoadConfig(agent_speed=agent_speed).max_steps
    outcomes, steps = [], []
    for i in range(episodes):
        world = generate_world(RoadConfig(agent_speed=0.5), EVAL_SEED_START + i)
        case = Case("oracle", agent_speed, k, EVAL_SEED_START + i)
        planner = MCTSPlanner(MCTSConfig(rollout_steps=k, prior_weights=weights), agent_speed, max_steps,
                              seed=case.planner_seed())  # fmt: skip
        result = run_episode(world, planner, OracleModel(world), agent_speed, k)
        outcomes.append(result.outcome)
        if result.outcome != "death":
            steps.append(result.steps)
    return {"weights": list(weights), "G": outcomes.count("goal"), "T": outcomes.count("timeout"),
            "D": outcomes.count("death"), "S_mean": round(float(np.mean(steps)), 1),
            "S_std": round(float(np.std(steps)), 1)}  # fmt: skip


def main(argv: list[str] | None = None) -> None:
    parser = CommandParser(prog="python -m lab.prior", description=__doc__)
    parser.add_argument("--episodes", type=int, default=100)
    args = parser.parse_args(argv)
    for weights in (PAPER_PRIOR, FLAT_PRIOR):
        print(json.dumps(oracle_with_prior(weights, args.episodes)))


if __name__ == "__main__":
    run_command(main, "python -m lab.prior")
