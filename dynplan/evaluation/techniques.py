"""The techniques an evaluation compares, in one table: what each needs, how its forward model is built, and its
order in Table 1.

A technique is a forward model behind the planner's seam (docs/protocol.md §3) — the oracle's true future, an
empty road, or a learned world model merging decoder samples or code futures — or no model at all (the random
agent, which does not search). `TECHNIQUES` is ordered as Table 1 lists them; `register_technique` adds one (a
new forward model plays through `flows.evaluate`, the table and `flows.replay` with nothing else to change).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass

from dynplan.env.road import World
from dynplan.models.registry import caution_for
from dynplan.models.weights import world_model_paths
from dynplan.planning.forward import ForwardModel, OracleModel, ZeroModel


@dataclass(frozen=True)
class AgentInputs:
    """What a technique may build its forward model from: the recorded world (the oracle reads its future), the
    world-model configuration of a learned technique, the seed of its random draws (the evaluation gives every case
    of a world the world's seed, so that they share each frame's draws), where a pipeline's own weights are (None:
    the committed ones), what overrides the configuration's caution and where a learned model generates ("cpu" or
    "cuda")."""

    world: World
    model: str | None = None
    seed: int = 0
    model_dir: str | os.PathLike | None = None
    caution: Mapping[str, float] | None = None
    device: str = "cpu"


@dataclass(frozen=True)
class Technique:
    """One row family of Table 1. `forward` builds the forward model (None: the agent uses none); `world_model`:
    it needs a world-model configuration; `search`: it plans with MCTS over k steps (the random agent does not)."""

    name: str
    description: str
    forward: Callable[[AgentInputs], ForwardModel | None]
    world_model: bool = False
    search: bool = True
    samples: int = 0  # decoder samples merged (learned techniques)
    futures: int = 0  # code futures sampled from the prior and merged (learned techniques)


def learned_model(
    model: str,
    samples: int,
    seed: int,
    futures: int = 0,
    model_dir: str | os.PathLike | None = None,
    caution: Mapping[str, float] | None = None,
    device: str = "cpu",
) -> ForwardModel:
    """The learned forward model of configuration `model` (weights loaded once per content; see
    `world_model_paths`), with the configuration's own caution except where `caution` (field → value) overrides
    it, generating batches on `device`."""
    from dynplan.models.world_model import LearnedWorldModel, world_model_parts  # torch: on use

    parts = world_model_parts(world_model_paths(model, model_dir), model)
    return LearnedWorldModel(
        *parts, samples=samples, futures=futures, seed=seed, caution=caution_for(model, caution), device=device
    )


def _learned(samples: int, futures: int) -> Callable[[AgentInputs], ForwardModel]:
    def build(inputs: AgentInputs) -> ForwardModel:
        return learned_model(
            inputs.model, samples, inputs.seed, futures, inputs.model_dir, inputs.caution, inputs.device
        )

    return build


#: name → technique, in Table 1's order.
TECHNIQUES: dict[str, Technique] = {}


def register_technique(technique: Technique, replace: bool = False) -> Technique:
    """Add `technique` to the table (after the others); an existing name is refused unless `replace`."""
    if technique.name in TECHNIQUES and not replace:
        raise ValueError(f"technique {technique.name!r} is registered already")
    TECHNIQUES[technique.name] = technique
    return technique


def technique(name: str) -> Technique:
    """The technique called `name` (a ValueError naming the known ones otherwise)."""
    try:
        return TECHNIQUES[name]
    except KeyError:
        raise ValueError(f"unknown technique {name!r}; known: {sorted(TECHNIQUES)}") from None


def learned_technique(name: str, samples: int = 0, futures: int = 0, description: str = "") -> Technique:
    """A technique that plans with a world model, merging `samples` decoder samples and `futures` code futures
    with the greedy future (both 0: the greedy future's mid-point frames, the paper's Mid)."""
    description = description or f"learned model, {samples} samples, {futures} futures"
    return Technique(name, description, _learned(samples, futures), world_model=True, samples=samples, futures=futures)


for _t in (
    Technique("oracle", "the true future (an upper bound)", lambda i: OracleModel(i.world)),
    learned_technique("mid", 0, 0, "learned model: the greedy future's mid-point frames (the paper's Mid)"),
    learned_technique("samples5", 5, 0, "learned model: the greedy future merged with 5 decoder samples"),
    learned_technique("samples10", 10, 0, "learned model: the greedy future merged with 10 decoder samples"),
    Technique("zero", "an empty road, goal unknown (a lower bound)", lambda i: ZeroModel()),
    Technique("random", "uniformly random actions, no search", lambda i: None, search=False),
    learned_technique("futures5", 0, 5, "learned model: 5 code futures sampled from the prior (beyond the paper)"),
):
    register_technique(_t)
