"""Freeway's pipeline presets and its evaluation plan (`collect-train-eval --world freeway`).

Every run but `smoke` records the 8 game modes, and the world model trains on the modes `split_of` gives it:
- `quick`: both stages from scratch with short budgets, then the oracle and the learned agent play one episode of
  mode 0 on the real game — end to end in minutes.
- `full`: the committed weights and the committed evaluation (modes 0 and 4, 20 episodes, every technique).
- `smoke`: tiny models on modes 0–5 (mode 5 the validation's); always-UP plays one episode (a learned tiny model
  would spend minutes on 2,048 steps).
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from dynplan.config import Config
from dynplan.pipeline.presets import SMOKE_BUDGET, PipelinePreset, StagePlan
from dynplan.training.budget import TrainBudget
from dynplan.worlds.freeway.evaluation import TECHNIQUES, FreewayPlan
from dynplan.worlds.freeway.models import CONFIGURATION
from dynplan.worlds.freeway.search import ChickenSearch


class FreewayEvalPlan(Config):
    """Which Freeway episodes to play on the real game (see `dynplan.worlds.freeway.evaluation`)."""

    world: Literal["freeway"] = Field("freeway", description="the world this evaluation plays")
    techniques: tuple[str, ...] = Field(("oracle", "learned"), description="techniques to play")
    modes: tuple[int, ...] = Field((0,), min_length=1, description="game modes, each 0 … 7")
    episodes: int = Field(20, ge=1, le=1000, description="episodes (NOOP starts) per mode")
    seed: int = Field(0, ge=0, le=2**31, description="seed of the NOOP starts' draw")
    horizon: int = Field(8, ge=1, le=64, description="the search's horizon k")

    @model_validator(mode="after")
    def _check(self) -> FreewayEvalPlan:
        unknown = [t for t in self.techniques if t not in TECHNIQUES]
        if unknown:
            raise ValueError(f"unknown techniques {unknown}; known: {list(TECHNIQUES)}")
        for mode in self.modes:
            FreewayPlan(mode=mode)
        ChickenSearch(horizon=self.horizon)
        return self

    @property
    def learned_techniques(self) -> tuple[str, ...]:
        return tuple(t for t in self.techniques if t == "learned")

    def plans(self) -> list[FreewayPlan]:
        """The episodes of each mode."""
        return [FreewayPlan(mode=m, episodes=self.episodes, seed=self.seed) for m in self.modes]


# The quick budgets: the tokenizer's epoch of 1,000 batches takes about 18 s on 2 cores, the prior's of 500 about
# 100 s; validation scores few items. `--world freeway --preset quick` is measured in docs/worlds.md.
_QUICK_VQVAE = StagePlan(budget=TrainBudget(epochs=12, steps_per_epoch=1000, val_frames=200))
_QUICK_PIXELCNN = StagePlan(budget=TrainBudget(epochs=4, steps_per_epoch=500, val_frames=100))
_SMOKE_VQVAE = StagePlan(
    overrides={"channels": (8, 8), "residual_blocks": 0, "latent_dim": 4, "codebook_size": 16, "batch_size": 64},
    budget=SMOKE_BUDGET,
)
_SMOKE_PIXELCNN = StagePlan(
    overrides={"channels": 8, "layers": 2, "condition_channels": 8, "embed_dim": 4, "batch_size": 8},
    budget=SMOKE_BUDGET,
)
_MODES = 8  # every game mode is recorded; the split decides which the world model trains on
_SMOKE_MODES = 6  # up to mode 5, the validation's
_MODEL = CONFIGURATION.name


def _preset(name: str, description: str, evaluation: FreewayEvalPlan, modes: int = _MODES, **stages) -> PipelinePreset:
    return PipelinePreset(
        name=name,
        world="freeway",
        description=description,
        train_episodes=modes,
        models=(_MODEL,),
        evaluation=evaluation,
        **stages,
    )


PRESETS: dict[str, PipelinePreset] = {
    "quick": _preset(
        "quick",
        "Freeway end to end in minutes: both stages from scratch, oracle and learned on one episode.",
        FreewayEvalPlan(techniques=("oracle", "learned"), modes=(0,), episodes=1),
        vqvae={_MODEL: _QUICK_VQVAE},
        pixelcnn={_MODEL: _QUICK_PIXELCNN},
    ),
    "full": _preset(
        "full",
        "Freeway's committed weights and evaluation: modes 0 and 4, 20 episodes, every technique.",
        FreewayEvalPlan(techniques=TECHNIQUES, modes=(0, 4), episodes=20),
        pretrained=True,
        vqvae={_MODEL: StagePlan(budget=TrainBudget(**CONFIGURATION.budgets["vqvae"]))},
        pixelcnn={_MODEL: StagePlan(budget=TrainBudget(**CONFIGURATION.budgets["pixelcnn"]))},
    ),
    "smoke": _preset(
        "smoke",
        "Freeway's every stage on tiny models in a minute (tests, deployment checks).",
        FreewayEvalPlan(techniques=("up",), modes=(0,), episodes=1),
        modes=_SMOKE_MODES,
        vqvae={_MODEL: _SMOKE_VQVAE},
        pixelcnn={_MODEL: _SMOKE_PIXELCNN},
    ),
}
