"""Planning against a predicted future: the forward-model seam, PUCT MCTS and the episode loop (docs/protocol.md §3)."""

from dynplan.planning.episode import EpisodeResult, run_episode, run_episodes
from dynplan.planning.forward import ForwardModel, OracleModel, Prediction, ZeroModel, goal_centres
from dynplan.planning.mcts import MCTSConfig, MCTSPlanner, RandomPlanner

__all__ = [
    "EpisodeResult",
    "ForwardModel",
    "MCTSConfig",
    "MCTSPlanner",
    "OracleModel",
    "Prediction",
    "RandomPlanner",
    "ZeroModel",
    "goal_centres",
    "run_episode",
    "run_episodes",
]
