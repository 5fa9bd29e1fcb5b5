"""Run-scale presets of the collect-train-eval pipeline: how much to collect, how long to train each world-model
stage, what to evaluate. Presets are data — `PIPELINE_PRESETS` — validated like every other config.

- `quick`: the README's main command; end to end on a 2-core laptop in minutes with small models trained from
  scratch and a few evaluation episodes. Its numbers show that the pipeline works, not how well the paper's
  system plans.
- `full`: the paper's protocol — 3,000 training episodes, both world-model configurations, 100 evaluation
  episodes per case, every technique, both agent speeds, k = 1, 3, 5, 10 — starting from the committed weights
  where they exist (training them took hours here) instead of retraining.
- `smoke`: the smallest run that exercises every stage, for tests and the deployment check.
"""

from __future__ import annotations

from typing import Any

from pydantic import Field, model_validator

from dynplan.config import Config
from dynplan.env.worlds import DEFAULT_WORLD
from dynplan.evaluation.cases import AGENT_SPEEDS, ROLLOUT_STEPS
from dynplan.evaluation.techniques import TECHNIQUES
from dynplan.models.pixelcnn import PixelCNNConfig
from dynplan.models.registry import models_of, world_model_spec
from dynplan.models.vqvae import VQVAEConfig
from dynplan.training.loop import TrainBudget


class StagePlan(Config):
    """One training stage: the model preset's config with `overrides`, trained for `budget`."""

    overrides: dict[str, Any] = Field(default_factory=dict, description="config fields replacing the preset's")
    budget: TrainBudget = Field(default_factory=TrainBudget, description="epochs, batches per epoch, threads")


class EvalPlan(Config):
    """Which cases of Table 1 to play (see `dynplan.evaluation.protocol`)."""

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


class PipelinePreset(Config):
    """Everything a collect-train-eval run does, by stage."""

    name: str = Field(description="preset name; the run's outputs go to OUT/<name>/")
    description: str = Field("", description="one line for humans (the deployment's description)")
    train_episodes: int = Field(ge=5, le=1_000_000, description="episodes recorded for training (seeds 0 …)")
    models: tuple[str, ...] = Field(("default",), description="world-model configurations (registry names)")
    pretrained: bool = Field(False, description="use the committed weights of a configuration instead of training")
    vqvae: dict[str, StagePlan] = Field(default_factory=dict, description="VQ-VAE stage per configuration")
    pixelcnn: dict[str, StagePlan] = Field(default_factory=dict, description="PixelCNN stage per configuration")
    evaluation: EvalPlan = Field(default_factory=EvalPlan)
    report_episodes: int = Field(10, ge=1, le=100, description="held-out episodes for the prediction-error figure")

    @model_validator(mode="after")
    def _check(self) -> PipelinePreset:
        if not set(self.models) <= set(models_of(DEFAULT_WORLD)):
            raise ValueError(f"models must be among {sorted(models_of(DEFAULT_WORLD))}, got {self.models}")
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
        return PixelCNNConfig(**{**world_model_spec(model).prior.model_dump(), **self.pixelcnn_plan(model).overrides,
                                 "codebook_size": k})  # fmt: skip

    @property
    def learned_techniques(self) -> tuple[str, ...]:
        return tuple(t for t in self.evaluation.techniques if TECHNIQUES[t].world_model)


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
# Tiny models: every stage runs, nothing is learned.
_SMOKE_BUDGET = TrainBudget(epochs=1, steps_per_epoch=5, val_frames=20, threads=1)
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
    budget=_SMOKE_BUDGET,
)
_SMOKE_PIXELCNN = StagePlan(
    overrides={"channels": 8, "layers": 2, "condition_channels": 8, "embed_dim": 4, "batch_size": 8},
    budget=_SMOKE_BUDGET,
)

_BOTH = ("default", "paper")

PIPELINE_PRESETS: dict[str, PipelinePreset] = {
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
