"""An agent as one frozen, validated spec: what plans — a technique and, for a learned one, its world-model
configuration, weights and caution — and how — samples, futures, playouts, horizon, device, seed.

Evaluation, replay, play, the evaluation benchmarks and every flow build one `AgentSpec` from their arguments and
pass it whole; the rules about an agent's settings (ranges, "occupancy needs patch-local codes", a known technique
and configuration, a device that exists) are checked when the spec is made. An evaluation plays many cases with
one spec: `for_case` gives each case's own (its technique, configuration, horizon and seed).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, TypeAlias

from pydantic import Field, field_validator, model_validator

from dynplan.config import Config, ConfigError
from dynplan.env.config import RoadConfig
from dynplan.env.road import World
from dynplan.evaluation.techniques import TECHNIQUES, AgentInputs, Technique, learned_technique, technique
from dynplan.models.caution import Caution
from dynplan.models.device import check_device
from dynplan.models.registry import caution_for, models_of, world_model_spec
from dynplan.models.weights import world_model_paths
from dynplan.planning.config import MCTSConfig
from dynplan.planning.forward import ForwardModel
from dynplan.world import DEFAULT_WORLD

if TYPE_CHECKING:  # the search compiles with numba and the world model needs torch: imported where they are used
    from dynplan.planning.mcts import MCTSPlanner, RandomPlanner

#: The technique name of a learned world model with the spec's own `samples` and `futures`.
LEARNED = "model"

Planner: TypeAlias = "MCTSPlanner | RandomPlanner"


class AgentSpec(Config):
    """One agent. A registered technique sets its own samples and futures; `technique="model"` is the learned world
    model with the spec's. A technique without a world model has no configuration (`model` is None)."""

    technique: str = Field(
        "samples5",
        description="a registered technique (oracle, mid, samples5, …) or 'model': "
        "the learned world model with `samples` and `futures`",
    )
    model: str | None = Field("default", description="world-model configuration of a learned technique")
    model_dir: str | None = Field(
        None, description="a pipeline's own weights, MODEL_DIR/<model>/{vqvae,pixelcnn}.pt (None: the committed ones)"
    )
    caution: dict[str, float] = Field(
        default_factory=dict,
        description="what overrides the configuration's own caution, field → value (occupancy, margin)",
    )
    samples: int = Field(0, ge=0, le=64, description="decoder samples merged with the greedy future ('model' only)")
    futures: int = Field(0, ge=0, le=64, description="futures sampled from the prior and merged ('model' only)")
    playouts: int = Field(100, ge=1, le=1_000_000, description="MCTS playouts per decision")
    rollout_steps: int = Field(3, ge=1, le=64, description="horizon k: predicted frames the search consults")
    device: str = Field("cpu", description="where a learned model generates its batches: cpu or cuda[:N]")
    seed: int = Field(0, ge=0, le=2**62, description="seed of the world model's draws and the planner's own")

    @model_validator(mode="before")
    @classmethod
    def _no_model_without_a_world_model(cls, data: Any) -> Any:
        """A technique that plans without a world model has no configuration: whatever `model` says is dropped."""
        named = isinstance(data, dict) and data.get("technique") in TECHNIQUES
        return {**data, "model": None} if named and not TECHNIQUES[data["technique"]].world_model else data

    @field_validator("device")
    @classmethod
    def _device(cls, v: str) -> str:
        return check_device(v)

    @model_validator(mode="after")
    def _check(self) -> AgentSpec:
        if self.technique != LEARNED and self.technique not in TECHNIQUES:
            raise ValueError(f"technique must be one of {[*TECHNIQUES, LEARNED]}, got {self.technique!r}")
        Caution(**self.caution)  # the overrides' ranges, whatever the technique
        if self.technique != LEARNED and (self.samples or self.futures):
            raise ValueError(
                f"samples and futures are technique {self.technique!r}'s own; give them with technique {LEARNED!r}"
            )
        if self.plans_with.world_model:
            if self.model not in models_of(DEFAULT_WORLD):
                raise ValueError(f"model must be one of {sorted(models_of(DEFAULT_WORLD))}, got {self.model!r}")
            try:
                self.own_caution.check_fits(world_model_spec(self.model).tokenizer.local, self.model)
            except ConfigError as error:
                raise ValueError(str(error).removeprefix("Caution: ")) from None
        return self

    @property
    def plans_with(self) -> Technique:
        """The technique: registered, or the learned world model with this spec's samples and futures."""
        if self.technique == LEARNED:
            return learned_technique(LEARNED, self.samples, self.futures)
        return technique(self.technique)

    @property
    def own_caution(self) -> Caution:
        """The caution a learned model plays with: its configuration's own, with this spec's overrides."""
        return caution_for(self.model or "", self.caution)

    def for_case(self, technique_name: str, model: str | None, rollout_steps: int | None, seed: int) -> AgentSpec:
        """This spec for one case of an evaluation: its technique, configuration, horizon (None: the random agent,
        which does not search) and seed."""
        return AgentSpec(
            **{
                **self.model_dump(),
                "technique": technique_name,
                "model": model,
                "rollout_steps": rollout_steps or self.rollout_steps,
                "seed": seed,
            }
        )

    def check_weights(self) -> None:
        """Check and load (and cache) a learned agent's checkpoints before anything plays: a CheckpointError names
        the file that is missing, damaged, of the wrong shapes, non-finite, unlike its model card or another
        configuration's, or whose tokenizer cannot take the agent's caution."""
        from dynplan.models.checkpoint import CheckpointError
        from dynplan.models.world_model import world_model_parts

        if self.plans_with.world_model:
            paths = world_model_paths(self.model, self.model_dir)
            tokenizer, _ = world_model_parts(paths, self.model)
            try:
                self.own_caution.check_fits(tokenizer.config.local, tokenizer.config.name)
            except ConfigError as error:
                raise CheckpointError(f"{paths[0]}: {str(error).removeprefix('Caution: ')}") from None

    def forward(self, world: World) -> ForwardModel | None:
        """The forward model this agent plans against on the recorded `world` (None: it uses none)."""
        inputs = AgentInputs(world, self.model, self.seed, self.model_dir, self.caution, self.device)
        return self.plans_with.forward(inputs)

    def planner(self, agent_speed: float, max_steps: int, seed: int | None = None) -> Planner:
        """The planner at `agent_speed` for an episode of `max_steps`, seeded by `seed` (default: the spec's)."""
        from dynplan.planning.mcts import MCTSPlanner, RandomPlanner

        seed = self.seed if seed is None else seed
        if not self.plans_with.search:
            return RandomPlanner(seed)
        config = MCTSConfig(rollout_steps=self.rollout_steps, playouts=self.playouts)
        return MCTSPlanner(config, agent_speed, max_steps, seed=seed)

    def build(
        self, world: World, agent_speed: float, planner_seed: int | None = None
    ) -> tuple[Planner, ForwardModel | None]:
        """The planner and forward model that play the recorded `world` at `agent_speed`."""
        max_steps = RoadConfig.from_dict(world.config.model_dump(), agent_speed=agent_speed).max_steps
        return self.planner(agent_speed, max_steps, planner_seed), self.forward(world)
