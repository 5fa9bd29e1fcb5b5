"""The cases of an evaluation (docs/protocol.md §4): which episodes, speeds, horizons and techniques, one `Case` per
played episode, and the seed ranges that keep evaluation and validation apart."""

from __future__ import annotations

import zlib
from dataclasses import dataclass

from pydantic import Field, model_validator

from dynplan.config import Config
from dynplan.env.config import RoadConfig
from dynplan.evaluation.techniques import technique
from dynplan.models.registry import models_of, world_model_spec
from dynplan.planning.config import MCTSConfig
from dynplan.world import DEFAULT_WORLD


def road_models() -> list[str]:
    """The world-model configurations of the road, the world of Table 1's cases, as registered."""
    return models_of(DEFAULT_WORLD)


#: The evaluation episodes' seeds: a range of their own, far from training seeds (which start at 0).
EVAL_SEED_START = 1_000_000
#: Validation episodes: where a world model's settings (prior epoch, occupancy threshold) are chosen, so that the
#: evaluation episodes only ever score a choice already made.
VALIDATION_SEED_START = 2_000_000
EVAL_EPISODES = 100
AGENT_SPEEDS = (1.0, 0.5)
ROLLOUT_STEPS = (1, 3, 5, 10)
#: The complete Table 1: per agent speed, its techniques (learned ones with every world-model configuration). The
#: 2× agent has every technique; the 1× agent the paper's rows (oracle, 5 samples) and the two bounds.
TABLE1 = {
    1.0: ("oracle", "mid", "samples5", "samples10", "zero", "random", "futures5"),
    0.5: ("oracle", "samples5", "zero", "random"),
}


@dataclass(frozen=True)
class Case:
    """One evaluation episode. `rollout_steps` is None for the random agent, which does not search."""

    technique: str
    agent_speed: float
    rollout_steps: int | None
    seed: int
    model: str | None = None  # the world-model configuration of a learned technique ("default" or "paper")

    def __post_init__(self) -> None:
        needs = technique(self.technique).world_model
        if needs != (self.model is not None):
            uses = "needs a world model" if needs else "does not use a world model"
            raise ValueError(f"technique {self.technique!r} {uses} (got model={self.model!r})")
        if self.model is not None and self.model not in road_models():
            raise ValueError(f"model must be one of {sorted(road_models())}, got {self.model!r}")

    @property
    def group(self) -> str:
        return case_group(self.technique, self.model, self.agent_speed, self.rollout_steps)

    def planner_seed(self) -> int:
        """A seed for the planner's own randomness, fixed per case."""
        return planner_seed(self.group, self.seed)


def case_group(technique_name: str, model: str | None, agent_speed: float, rollout_steps: int | None) -> str:
    """The name of a case's group (technique and configuration, speed, horizon; None: no search)."""
    k = "none" if rollout_steps is None else rollout_steps
    label = technique_name if model is None else f"{technique_name}-{model}"
    return f"{label}/speed{agent_speed:g}_k{k}"


def planner_seed(group: str, seed: int) -> int:
    """The seed of a planner's own randomness on the world of `seed` in the case group `group`."""
    return zlib.crc32(f"{group}/{seed}".encode())


def cases(
    techniques: list[str],
    speeds: tuple[float, ...] = AGENT_SPEEDS,
    rollout_steps: tuple[int, ...] = ROLLOUT_STEPS,
    episodes: int = EVAL_EPISODES,
    first_seed: int = EVAL_SEED_START,
    models: tuple[str, ...] = ("default",),
) -> list[Case]:
    """Every case of the table: the random agent once per speed, searching techniques once per horizon, learned
    techniques once per world-model configuration in `models`."""
    out = []
    for name in techniques:
        t = technique(name)
        ks: tuple[int | None, ...] = rollout_steps if t.search else (None,)
        for model in models if t.world_model else (None,):
            for speed in speeds:
                for k in ks:
                    out += [Case(name, speed, k, first_seed + i, model) for i in range(episodes)]
    return out


def table1_cases(
    episodes: int = EVAL_EPISODES, first_seed: int = EVAL_SEED_START, rollout_steps: tuple[int, ...] = ROLLOUT_STEPS
) -> list[Case]:
    """Every case of the complete Table 1 (`TABLE1`), learned techniques with every world-model configuration."""
    models = tuple(road_models())
    return [
        case
        for speed, names in TABLE1.items()
        for case in cases(list(names), (speed,), rollout_steps, episodes, first_seed, models)
    ]


class CasePlan(Config):
    """Which cases an evaluation plays: techniques × world-model configurations × agent speeds × horizons × episodes
    (seeds `first_seed` …), or with `table1` every case of the complete Table 1 (`TABLE1`, every configuration)."""

    techniques: tuple[str, ...] = Field(("oracle", "zero", "random"), description="registered techniques")
    models: tuple[str, ...] = Field(("default",), description="world-model configurations of the learned techniques")
    agent_speeds: tuple[float, ...] = Field(AGENT_SPEEDS, description="agent speeds: 1.0 (2×) and/or 0.5 (1×)")
    rollout_steps: tuple[int, ...] = Field(ROLLOUT_STEPS, description="horizons k of the searching techniques")
    episodes: int = Field(EVAL_EPISODES, ge=1, le=10_000_000, description="episodes per case")
    first_seed: int = Field(
        EVAL_SEED_START, ge=0, le=2**62, description="seed of the first episode (validation: 2000000)"
    )
    table1: bool = Field(False, description="every case of the complete Table 1, whatever the lists above say")

    @model_validator(mode="after")
    def _check(self) -> CasePlan:
        for name in self.techniques:
            technique(name)  # a ValueError naming the known ones
        for model in self.models:
            world_model_spec(model)
        for speed in self.agent_speeds:
            RoadConfig(agent_speed=speed)
        for k in self.rollout_steps:
            MCTSConfig(rollout_steps=k)
        return self

    def cases(self) -> list[Case]:
        """Every case of the plan."""
        if self.table1:
            return table1_cases(self.episodes, self.first_seed, self.rollout_steps)
        return cases(
            list(self.techniques), self.agent_speeds, self.rollout_steps, self.episodes, self.first_seed, self.models
        )

    def pairs(self) -> list[tuple[str, str | None]]:
        """Each (technique, world-model configuration) the plan plays (None: a technique without one), in Table 1's
        order."""
        table = TABLE1.items() if self.table1 else [(speed, self.techniques) for speed in self.agent_speeds]
        models = tuple(road_models()) if self.table1 else self.models
        names = dict.fromkeys(name for _, names in table for name in names)
        return [
            (name, model if technique(name).world_model else None)
            for name in names
            for model in (models if technique(name).world_model else (None,))
        ]
