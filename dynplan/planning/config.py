"""The settings of the PUCT search (`MCTSConfig`; docs/protocol.md §3), apart from the compiled search
(`mcts.py`) so that a command can check them without compiling or importing numba."""

from __future__ import annotations

from pydantic import Field, field_validator

from dynplan.config import Config
from dynplan.env.agent import N_ACTIONS

#: The paper's goal prior: weights by rank of angular distance between action heading and goal bearing.
PAPER_PRIOR = (4.0, 3.0, 2.0, 2.0, 1.0, 1.0, 1.0, 1.0)


class MCTSConfig(Config):
    """PUCT search settings; defaults are the paper's (docs/protocol.md §3) except the horizon, which Table 1 varies."""

    rollout_steps: int = Field(3, ge=1, le=64, description="horizon k: predicted frames the search consults")
    playouts: int = Field(100, ge=1, le=1_000_000, description="playouts per decision")
    c_puct: float = Field(1.4, gt=0.0, le=100.0, description="exploration constant c")
    temperature: float = Field(0.01, gt=0.0, le=100.0, description="temperature on visit counts")
    prior_weights: tuple[float, ...] = Field(PAPER_PRIOR, description="8 weights by heading rank")

    @field_validator("prior_weights")
    @classmethod
    def _eight_non_negative(cls, v: tuple[float, ...]) -> tuple[float, ...]:
        if len(v) != N_ACTIONS or min(v) < 0 or sum(v) <= 0:
            raise ValueError(f"prior_weights must be {N_ACTIONS} non-negative numbers with a positive sum")
        return v
