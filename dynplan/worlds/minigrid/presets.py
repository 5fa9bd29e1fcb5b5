"""MiniGrid's pipeline presets and its evaluation plan (`collect-train-eval --world minigrid`).

Every run records its training rooms (seeds 0 …) and evaluates on rooms from 1,000,000 on, which no setting was
chosen on and no model trained on:
- `quick`: both stages from scratch on 200 rooms with short budgets, then the learned agent (10 and 1 samples), the
  oracle and stand-still over 20 rooms — end to end in minutes.
- `full`: the committed weights and the committed evaluation's protocol: every technique over 200 rooms.
- `smoke`: tiny models; the oracle and the 1-sample learned agent play one room.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from dynplan.config import Config
from dynplan.pipeline.presets import SMOKE_BUDGET, PipelinePreset, StagePlan
from dynplan.training.budget import TrainBudget
from dynplan.worlds.minigrid.commands import EVAL_SEED
from dynplan.worlds.minigrid.evaluation import TECHNIQUES
from dynplan.worlds.minigrid.models import CONFIGURATION
from dynplan.worlds.minigrid.results import LEARNED_SAMPLES


class MiniGridEvalPlan(Config):
    """Which MiniGrid rooms each technique plays (see `dynplan.worlds.minigrid.evaluation`)."""

    world: Literal["minigrid"] = Field("minigrid", description="the world this evaluation plays")
    techniques: tuple[str, ...] = Field(TECHNIQUES, min_length=1, description="techniques to play")
    episodes: int = Field(200, ge=1, le=1_000_000, description="rooms per technique")
    first_seed: int = Field(EVAL_SEED, ge=0, le=2**62 - 1_000_000, description="seed of the first room")
    samples: int = Field(64, ge=1, le=4096, description="futures the walk technique samples a decision")

    @model_validator(mode="after")
    def _check(self) -> MiniGridEvalPlan:
        unknown = [t for t in self.techniques if t not in TECHNIQUES]
        if unknown:
            raise ValueError(f"unknown techniques {unknown}; known: {list(TECHNIQUES)}")
        return self

    @property
    def learned_techniques(self) -> tuple[str, ...]:
        return tuple(t for t in self.techniques if t in LEARNED_SAMPLES)


# The quick budgets: the tokenizer's whole budget (exact on the room's 2 × 2 patches from its third epoch of 500
# batches; fewer leave balls undecoded) takes seconds; the prior's epoch of 500 batches about 25 s on a core.
# `--world minigrid --preset quick` is measured in docs/minigrid.md.
_QUICK_VQVAE = StagePlan(budget=TrainBudget(**CONFIGURATION.budgets["vqvae"]))
_QUICK_PIXELCNN = StagePlan(budget=TrainBudget(epochs=8, steps_per_epoch=500, val_frames=200))
_SMOKE_PIXELCNN = StagePlan(
    overrides={"channels": 8, "layers": 2, "condition_channels": 8, "embed_dim": 4, "batch_size": 8},
    budget=SMOKE_BUDGET,
)
_MODEL = CONFIGURATION.name


def _preset(name: str, description: str, train_episodes: int, evaluation: MiniGridEvalPlan, **stages) -> PipelinePreset:
    return PipelinePreset(
        name=name,
        world="minigrid",
        description=description,
        train_episodes=train_episodes,
        models=(_MODEL,),
        evaluation=evaluation,
        **stages,
    )


PRESETS: dict[str, PipelinePreset] = {
    "quick": _preset(
        "quick",
        "MiniGrid end to end in minutes: both stages from scratch on 200 rooms, 4 techniques over 20 rooms.",
        200,
        MiniGridEvalPlan(techniques=("oracle", "learned10", "learned1", "stand_still"), episodes=20),
        vqvae={_MODEL: _QUICK_VQVAE},
        pixelcnn={_MODEL: _QUICK_PIXELCNN},
    ),
    "full": _preset(
        "full",
        "MiniGrid's committed weights and evaluation: every technique over 200 rooms.",
        1000,
        MiniGridEvalPlan(),
        pretrained=True,
        vqvae={_MODEL: StagePlan(budget=TrainBudget(**CONFIGURATION.budgets["vqvae"]))},
        pixelcnn={_MODEL: StagePlan(budget=TrainBudget(**CONFIGURATION.budgets["pixelcnn"]))},
    ),
    "smoke": _preset(
        "smoke",
        "MiniGrid's every stage on tiny models in a minute (tests, deployment checks).",
        5,
        MiniGridEvalPlan(techniques=("oracle", "learned1"), episodes=1),
        vqvae={_MODEL: StagePlan(budget=SMOKE_BUDGET)},
        pixelcnn={_MODEL: _SMOKE_PIXELCNN},
    ),
}
