"""How cautious the planner's view of a learned model's prediction is: beyond the paper, per configuration.

The paper plans on the greedy (argmax) future alone. Two settings make its frames more cautious, each chosen on
validation episodes (docs/design.md, occupancy and the lane margin): `occupancy` adds the pixels the prior
gives at least that probability of holding an obstacle; `margin` widens every predicted obstacle along its lane;
`span` limits both to the first frames ahead (the agent replans every step, so only the next frame's misses kill
at once; a caution over the whole horizon also blocks the road the agent would cross later).
The module itself needs only pydantic; the results store reads its fields to know a row's provenance.
"""

from __future__ import annotations

from pydantic import Field

from dynplan.config import Config


class Caution(Config):
    """Beyond the paper: how a learned model's frames are made more cautious before the planner sees them (both
    off: the paper's argmax alone). A result records the settings that are on (`recorded`)."""

    occupancy: float = Field(0.0, ge=0.0, lt=1.0, description="obstacle probability from which the prior's "
                             "unsure obstacles join the frames (0: off; needs patch-local codes)")  # fmt: skip
    margin: int = Field(0, ge=0, le=4, description="pixels each predicted obstacle is widened by along its lane, "
                        "both ways (0: off)")  # fmt: skip
    span: int = Field(0, ge=0, le=100, description="predicted frames, from the next, that occupancy and margin "
                      "cover (0: every frame)")  # fmt: skip

    def recorded(self) -> dict:
        """The settings that are on (what a result played with them records; an absent key means off)."""
        return {name: value for name, value in self.model_dump().items() if value}
