"""Run-scale presets of the collect-train-eval pipeline, per world: how much to collect, how long to train each
world-model stage, what to evaluate. Presets are data — `PIPELINE_PRESETS[world][name]` — validated like every
other config.

The road's:

- `quick`: the README's main command; end to end on a 2-core laptop in minutes with small models trained from
  scratch and a few evaluation episodes. Its numbers show that the pipeline works, not how well the paper's
  system plans.
- `full`: the paper's protocol — 3,000 training episodes, both world-model configurations, 100 evaluation
  episodes per case, every technique, both agent speeds, k = 1, 3, 5, 10 — starting from the committed weights
  where they exist (training them took hours here) instead of retraining.
- `smoke`: the smallest run that exercises every stage, for tests and the deployment check.

Freeway's (`--world freeway`; every run records the 8 game modes, and the world model trains on the modes
`split_of` gives it):
- `quick`: both stages from scratch with short budgets, then the oracle and the learned agent play one episode of
  mode 0 on the real game — end to end in minutes.
- `full`: the committed weights and the committed evaluation (modes 0 and 4, 20 episodes, every technique).
- `smoke`: tiny models; always-UP plays one episode (a learned tiny model would spend minutes on 2,048 steps).
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import Field, model_validator

from dynplan.config import Config
from dynplan.env.worlds import DEFAULT_WORLD, FREEWAY, ROAD, WORLDS
from dynplan.evaluation import freeway
from dynplan.evaluation.cases import AGENT_SPEEDS, ROLLOUT_STEPS
from dynplan.evaluation.techniques import TECHNIQUES
from dynplan.models.pixelcnn import PixelCNNConfig
from dynplan.models.registry import models_of, world_model_spec
from dynplan.models.vqvae import VQVAEConfig
from dynplan.planning.chicken import ChickenSearch
from dynplan.training.loop import TrainBudget


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


class FreewayEvalPlan(Config):
    """Which Freeway episodes to play on the real game (see `dynplan.evaluation.freeway`)."""

    world: Literal["freeway"] = Field("freeway", description="the world this evaluation plays")
    techniques: tuple[str, ...] = Field(("oracle", "learned"), description="techniques to play")
    modes: tuple[int, ...] = Field((0,), min_length=1, description="game modes, each 0 … 7")
    episodes: int = Field(20, ge=1, le=1000, description="episodes (NOOP starts) per mode")
    seed: int = Field(0, ge=0, le=2**31, description="seed of the NOOP starts' draw")
    horizon: int = Field(8, ge=1, le=64, description="the search's horizon k")

    @model_validator(mode="after")
    def _check(self) -> FreewayEvalPlan:
        unknown = [t for t in self.techniques if t not in freeway.TECHNIQUES]
        if unknown:
            raise ValueError(f"unknown techniques {unknown}; known: {list(freeway.TECHNIQUES)}")
        for mode in self.modes:
            freeway.FreewayPlan(mode=mode)
        ChickenSearch(horizon=self.horizon)
        return self

    @property
    def learned_techniques(self) -> tuple[str, ...]:
        return tuple(t for t in self.techniques if t == "learned")

    def plans(self) -> list[freeway.FreewayPlan]:
        """The episodes of each mode."""
        return [freeway.FreewayPlan(mode=m, episodes=self.episodes, seed=self.seed) for m in self.modes]


#: A world's evaluation plan, told apart by its `world` field.
Evaluation = Annotated[EvalPlan | FreewayEvalPlan, Field(discriminator="world")]


class PipelinePreset(Config):
    """Everything a collect-train-eval run does, by stage."""

    name: str = Field(description="preset name; the run's outputs go to OUT/<folder>/ (see `folder`)")
    world: str = Field(DEFAULT_WORLD, description=f"the world ({', '.join(WORLDS)})")
    description: str = Field("", description="one line for humans (the deployment's description)")
    train_episodes: int = Field(ge=5, le=1_000_000, description="episodes recorded for training (seeds 0 …)")
    models: tuple[str, ...] = Field(("default",), description="world-model configurations (registry names)")
    pretrained: bool = Field(False, description="use the committed weights of a configuration instead of training")
    vqvae: dict[str, StagePlan] = Field(default_factory=dict, description="VQ-VAE stage per configuration")
    pixelcnn: dict[str, StagePlan] = Field(default_factory=dict, description="PixelCNN stage per configuration")
    evaluation: Evaluation = Field(default_factory=EvalPlan)
    report_episodes: int = Field(10, ge=1, le=100, description="held-out episodes for the prediction-error figure")

    @model_validator(mode="before")
    @classmethod
    def _evaluation_of_the_world(cls, data: Any) -> Any:
        """An evaluation given without its world, or none, is the run's world's."""
        if isinstance(data, dict) and isinstance(evaluation := data.get("evaluation", {}), dict):
            world = data.get("world", DEFAULT_WORLD)
            data = {**data, "evaluation": {"world": world if world in WORLDS else DEFAULT_WORLD, **evaluation}}
        return data

    @model_validator(mode="after")
    def _check(self) -> PipelinePreset:
        if self.world not in WORLDS:
            raise ValueError(f"world {self.world!r} is not one of {', '.join(WORLDS)}")
        if not set(self.models) <= set(models_of(self.world)):
            raise ValueError(f"models must be among {sorted(models_of(self.world))}, got {self.models}")
        if self.evaluation.world != self.world:
            raise ValueError(f"the evaluation plays the {self.evaluation.world} world, not this run's {self.world}")
        last = WORLDS[self.world].seeds[1]
        if self.train_episodes > last + 1:
            raise ValueError(f"train_episodes={self.train_episodes} is invalid for the {self.world} world; valid range "
                             f"[5, {last + 1}] (its seeds 0 … {last})")  # fmt: skip
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

_ROAD_PRESETS: dict[str, PipelinePreset] = {
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

# Freeway's quick budgets: the tokenizer's epoch of 1,000 batches takes about 18 s on 2 cores, the prior's of 500
# about 100 s; validation scores few items. `--world freeway --preset quick` is measured in docs/worlds.md.
_FREEWAY_QUICK_VQVAE = StagePlan(budget=TrainBudget(epochs=12, steps_per_epoch=1000, val_frames=200))
_FREEWAY_QUICK_PIXELCNN = StagePlan(budget=TrainBudget(epochs=4, steps_per_epoch=500, val_frames=100))
_FREEWAY_SMOKE_VQVAE = StagePlan(
    overrides={"channels": (8, 8), "residual_blocks": 0, "latent_dim": 4, "codebook_size": 16, "batch_size": 64},
    budget=_SMOKE_BUDGET,
)
_FREEWAY_SMOKE_PIXELCNN = StagePlan(
    overrides={"channels": 8, "layers": 2, "condition_channels": 8, "embed_dim": 4, "batch_size": 8},
    budget=_SMOKE_BUDGET,
)
_FREEWAY = FREEWAY.name
_FREEWAY_MODES = 8  # every game mode is recorded; the split decides which the world model trains on

_FREEWAY_PRESETS: dict[str, PipelinePreset] = {
    "quick": PipelinePreset(
        name="quick",
        world=_FREEWAY,
        description="Freeway end to end in minutes: both stages from scratch, oracle and learned on one episode.",
        train_episodes=_FREEWAY_MODES,
        models=("freeway",),
        vqvae={"freeway": _FREEWAY_QUICK_VQVAE},
        pixelcnn={"freeway": _FREEWAY_QUICK_PIXELCNN},
        evaluation=FreewayEvalPlan(techniques=("oracle", "learned"), modes=(0,), episodes=1),
    ),
    "full": PipelinePreset(
        name="full",
        world=_FREEWAY,
        description="Freeway's committed weights and evaluation: modes 0 and 4, 20 episodes, every technique.",
        train_episodes=_FREEWAY_MODES,
        models=("freeway",),
        pretrained=True,
        vqvae={"freeway": StagePlan(budget=TrainBudget(**world_model_spec("freeway").budgets["vqvae"]))},
        pixelcnn={"freeway": StagePlan(budget=TrainBudget(**world_model_spec("freeway").budgets["pixelcnn"]))},
        evaluation=FreewayEvalPlan(techniques=freeway.TECHNIQUES, modes=(0, 4), episodes=20),
    ),
    "smoke": PipelinePreset(
        name="smoke",
        world=_FREEWAY,
        description="Freeway's every stage on tiny models in a minute (tests, deployment checks).",
        train_episodes=_FREEWAY_MODES,
        models=("freeway",),
        vqvae={"freeway": _FREEWAY_SMOKE_VQVAE},
        pixelcnn={"freeway": _FREEWAY_SMOKE_PIXELCNN},
        evaluation=FreewayEvalPlan(techniques=("up",), modes=(0,), episodes=1),
    ),
}

#: The presets of each world, by name.
PIPELINE_PRESETS: dict[str, dict[str, PipelinePreset]] = {ROAD.name: _ROAD_PRESETS, _FREEWAY: _FREEWAY_PRESETS}


def pipeline_preset(name: str, world: str = DEFAULT_WORLD) -> PipelinePreset:
    """The preset `name` of `world`; a ValueError naming the valid ones otherwise."""
    if world not in PIPELINE_PRESETS:
        raise ValueError(f"world {world!r} is not one of {', '.join(PIPELINE_PRESETS)}")
    if name not in PIPELINE_PRESETS[world]:
        raise ValueError(f"preset must be one of {sorted(PIPELINE_PRESETS[world])} for the {world} world, got {name!r}")
    return PIPELINE_PRESETS[world][name]
