"""Planning against a predicted future: the forward-model seam, PUCT MCTS and the episode loop (docs/protocol.md §3)."""

from dynplan.lazy import lazy_names

#: Each public name by its module, imported when first used (`dynplan.lazy`).
_PUBLIC = {
    "EpisodeResult": "dynplan.planning.episode",
    "ForwardModel": "dynplan.planning.forward",
    "MCTSConfig": "dynplan.planning.config",
    "MCTSPlanner": "dynplan.planning.mcts",
    "OracleModel": "dynplan.planning.forward",
    "Prediction": "dynplan.planning.forward",
    "RandomPlanner": "dynplan.planning.mcts",
    "ZeroModel": "dynplan.planning.forward",
    "goal_centres": "dynplan.planning.forward",
    "run_episode": "dynplan.planning.episode",
    "run_episodes": "dynplan.planning.episode",
}
__getattr__, __dir__ = lazy_names(__name__, _PUBLIC)
__all__ = sorted(_PUBLIC)
