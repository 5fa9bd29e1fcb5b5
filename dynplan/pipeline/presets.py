"""Run-scale presets of the collect-train-eval pipeline, per world: how much to collect, how long to train each
world-model stage, what to evaluate. Presets are data — `pipeline_presets(world)[name]`, each world's from its
`WorldParts.presets` — validated like every other config; a preset's evaluation is its world's plan
(`WorldParts.evaluation_plan`).

The road's:

- `quick`: the README's main command; end to end on a 2-core laptop in minutes with small models trained from
  scratch and a few evaluation episodes. Its numbers show that the pipeline works, not how well the paper's
  system plans.
- `full`: the paper's protocol — 3,000 training episodes, both world-model configurations, 100 evaluation
  episodes per case, every technique, both agent speeds, k = 1, 3, 5, 10 — starting from the committed weights
  where they exist (training them took hours here) instead of retraining.
- `smoke`: the smallest run that exercises every stage, for tests and the deployment check.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field, SerializeAsAny, model_validator

from dynplan.config import Config
from dynplan.evaluation.cases import AGENT_SPEEDS, ROLLOUT_STEPS
from dynplan.evaluation.techniques import TECHNIQUES
from dynplan.models.configs import PixelCNNConfig, VQVAEConfig
from dynplan.models.registry import models_of, world_model_spec
from dynplan.training.budget import TrainBudget
from dynplan.world import DEFAULT_WORLD, world, world_names


class StagePlan(Config):
    """One training stage: the model preset's config with `overrides`, trained for `budget`."""

    overrides: dict[str, Any] = Field(default_factory=dict, description="config fields replacing the preset's")
    budget: TrainBudget = Field(default_factory=TrainBudget, description="epochs, batches per epoch, threads")


class EvalPlan(Config):
    """Which cases of Table 1 to play (see `dynplan.evaluation.protocol`): the road's evaluation."""

    world: Literal["road"] = Field("road", description="the world this evaluation plays")
    episodes: int = Field(100, ge=1, le=10_000, description="evaluation episodes per case")
    techniques: tuple[str, ...] = Field(("oracle", "zero", "random", "mid", "samples5", "samples10"))
    agent_speeds: tuple[float, ...] = Field(AGENT_SPEEDS, description="1.0 (2×) and/or 0.5 (1×)")
    rollout_steps: tuple[int, ...] = Field(ROLLOUT_STEPS, description="k values")
    playouts: int = Field(100, ge=1, le=100_000, description="MCTS playouts per decision")

    @model_validator(mode="after")
    def _check(self) -> EvalPlan:
        unknown = [t for t in self.techniques if t not in TECHNIQUES]
        if unknown:
            raise ValueError(f"unknown techniques {unknown}; known: {sorted(TECHNIQUES)}")
        return self

    @property
    def learned_techniques(self) -> tuple[str, ...]:
        """The techniques that plan with the run's world models."""
        return tuple(t for t in self.techniques if TECHNIQUES[t].world_model)


def evaluation_plan(world_name: str) -> type[Config]:
    """The type of world `world_name`'s evaluation plan (the road's: `EvalPlan`); a ValueError if it has none."""
    plan = EvalPlan if world_name == DEFAULT_WORLD else world(world_name).load().evaluation_plan
    if plan is None:
        raise ValueError(f"the {world_name} world has no evaluation plan (its WorldParts.evaluation_plan)")
    return plan


class PipelinePreset(Config):
    """Everything a collect-train-eval run does, by stage."""

    name: str = Field(description="preset name; the run's outputs go to OUT/<folder>/ (see `folder`)")
    world: str = Field(DEFAULT_WORLD, description="the world (a registered world's name)")
    description: str = Field("", description="one line for humans (the deployment's description)")
    train_episodes: int = Field(ge=5, le=1_000_000, description="episodes recorded for training (seeds 0 …)")
    models: tuple[str, ...] = Field(("default",), description="world-model configurations (registry names)")
    pretrained: bool = Field(False, description="use the committed weights of a configuration instead of training")
    vqvae: dict[str, StagePlan] = Field(default_factory=dict, description="VQ-VAE stage per configuration")
    pixelcnn: dict[str, StagePlan] = Field(default_factory=dict, description="PixelCNN stage per configuration")
    evaluation: SerializeAsAny[Config] = Field(default_factory=EvalPlan, description="the world's evaluation plan")
    report_episodes: int = Field(10, ge=1, le=100, description="held-out episodes for the prediction-error figure")

    @model_validator(mode="before")
    @classmethod
    def _evaluation_of_the_world(cls, data: Any) -> Any:
        """An evaluation given as fields, or none, is a plan of its own world or else the run's world."""
        if isinstance(data, dict) and isinstance(evaluation := data.get("evaluation", {}), dict):
            name = evaluation.get("world", data.get("world", DEFAULT_WORLD))
            data = {
                **data,
                "evaluation": evaluation_plan(name if name in world_names() else DEFAULT_WORLD)(
                    **{"world": name if name in world_names() else DEFAULT_WORLD, **evaluation}
                ),
            }
        return data

    @model_validator(mode="after")
    def _check(self) -> PipelinePreset:
        if self.world not in world_names():
            raise ValueError(f"world {self.world!r} is not one of {', '.join(world_names())}")
        if not set(self.models) <= set(models_of(self.world)):
            raise ValueError(f"models must be among {sorted(models_of(self.world))}, got {self.models}")
        if self.evaluation.world != self.world:
            raise ValueError(f"the evaluation plays the {self.evaluation.world} world, not this run's {self.world}")
        last = world(self.world).seeds[1]
        if self.train_episodes > last + 1:
            raise ValueError(
                f"train_episodes={self.train_episodes} is invalid for the {self.world} world; valid range "
                f"[5, {last + 1}] (its seeds 0 … {last})"
            )
        for model in self.models:
            VQVAEConfig(**{**world_model_spec(model).tokenizer.model_dump(), **self.vqvae_plan(model).overrides})
            self.pixelcnn_config(model)
        return self

    def vqvae_plan(self, model: str) -> StagePlan:
        return self.vqvae.get(model, StagePlan())

    def pixelcnn_plan(self, model: str) -> StagePlan:
        return self.pixelcnn.get(model, StagePlan())

    def vqvae_config(self, model: str) -> VQVAEConfig:
        return VQVAEConfig(**{**world_model_spec(model).tokenizer.model_dump(), **self.vqvae_plan(model).overrides})

    def pixelcnn_config(self, model: str) -> PixelCNNConfig:
        """The prior's config; K always follows the VQ-VAE's codebook."""
        k = self.vqvae_config(model).codebook_size
        return PixelCNNConfig(
            **{**world_model_spec(model).prior.model_dump(), **self.pixelcnn_plan(model).overrides, "codebook_size": k}
        )

    @property
    def learned_techniques(self) -> tuple[str, ...]:
        return self.evaluation.learned_techniques

    @property
    def folder(self) -> str:
        """The run's folder under OUT: the preset's name (another world's: prefixed by the world)."""
        return self.name if self.world == DEFAULT_WORLD else f"{self.world}-{self.name}"


# Small models trained from scratch in minutes on 2 cores: the default tokenizer with 512 codes (4,096 would make
# the small prior's output layer 8× as wide), and a small prior.
_QUICK_VQVAE = StagePlan(
    overrides={"codebook_size": 512},
    budget=TrainBudget(epochs=10, steps_per_epoch=100, val_frames=500),
)
_QUICK_PIXELCNN = StagePlan(
    overrides={"channels": 32, "layers": 4, "condition_channels": 32, "learning_rate": 1e-3, "batch_size": 64},
    budget=TrainBudget(epochs=12, steps_per_epoch=60, val_frames=200),
)
#: Tiny models: every stage runs, nothing is learned.
SMOKE_BUDGET = TrainBudget(epochs=1, steps_per_epoch=5, val_frames=20, threads=1)
_SMOKE_VQVAE = StagePlan(
    overrides={
        "channels": (8, 8, 8),
        "strides": (2, 2, 2),
        "residual_blocks": 0,
        "latent_dim": 4,
        "codebook_size": 16,
        "learning_rate": 1e-3,
        "batch_size": 8,
    },
    budget=SMOKE_BUDGET,
)
_SMOKE_PIXELCNN = StagePlan(
    overrides={"channels": 8, "layers": 2, "condition_channels": 8, "embed_dim": 4, "batch_size": 8},
    budget=SMOKE_BUDGET,
)

_BOTH = ("default", "paper")

#: The road's presets, by name (`pipeline_presets`).
ROAD_PRESETS: dict[str, PipelinePreset] = {
    "quick": PipelinePreset(
        name="quick",
        description="End to end in minutes on a laptop: small models from scratch, 5 evaluation episodes.",
        train_episodes=60,
        models=("default",),
        vqvae={"default": _QUICK_VQVAE},
        pixelcnn={"default": _QUICK_PIXELCNN},
        evaluation=EvalPlan(episodes=5, techniques=("oracle", "mid"), agent_speeds=(1.0,), rollout_steps=(3,)),
        report_episodes=3,
    ),
    "full": PipelinePreset(
        name="full",
        description="The paper's protocol: both configurations (committed weights), 100 episodes, every case.",
        train_episodes=3000,
        models=("default", "paper"),
        pretrained=True,
        # each configuration's own training budgets (the registry's), so that retraining lands in their folders
        vqvae={m: StagePlan(budget=TrainBudget(**world_model_spec(m).budgets["vqvae"])) for m in _BOTH},
        pixelcnn={m: StagePlan(budget=TrainBudget(**world_model_spec(m).budgets["pixelcnn"])) for m in _BOTH},
        evaluation=EvalPlan(),
        report_episodes=10,
    ),
    "smoke": PipelinePreset(
        name="smoke",
        description="Every stage on tiny models in seconds (tests, deployment checks).",
        train_episodes=6,
        models=("default",),
        vqvae={"default": _SMOKE_VQVAE},
        pixelcnn={"default": _SMOKE_PIXELCNN},
        evaluation=EvalPlan(
            episodes=1, techniques=("oracle", "mid"), agent_speeds=(1.0,), rollout_steps=(1,), playouts=10
        ),
        report_episodes=1,
    ),
}


def pipeline_presets(world_name: str = DEFAULT_WORLD) -> dict[str, PipelinePreset]:
    """The presets of `world_name`, by name (its `WorldParts.presets`); a ValueError naming the worlds otherwise."""
    if world_name not in world_names():
        raise ValueError(f"world {world_name!r} is not one of {', '.join(world_names())}")
    return dict(world(world_name).load().presets)


def pipeline_preset(name: str, world_name: str = DEFAULT_WORLD) -> PipelinePreset:
    """The preset `name` of `world_name`; a ValueError naming the valid ones otherwise."""
    presets = pipeline_presets(world_name)
    if not presets:
        raise ValueError(f"preset {name!r}: the {world_name} world has no pipeline presets")
    if name not in presets:
        raise ValueError(f"preset must be one of {sorted(presets)} for the {world_name} world, got {name!r}")
    return presets[name]
