"""MiniGrid's runs in the results store (`dynplan.evaluation.store`, the same for every world): what a manifest and
a row hold, and the check that plays a row's recorded actions in its room again.

    <root>/runs/<run>/manifest.json   role, world `minigrid-v1`, the room's and the search's settings, every
                                      command that played the run
    <root>/runs/<run>/episodes.jsonl  one row per episode: its case (technique, world model, seed), how it ended,
                                      its steps, median decision ms, the actions and the code

The actions are run-length encoded (`L2F5R1…`: L turn left, R turn right, F forward, each with how many steps in a
row): the room is recorded from its seed, so a row's outcome and steps follow from its seed and actions alone.
"""

from __future__ import annotations

import itertools
import re
from collections.abc import Iterable, Mapping
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from dynplan.evaluation.store_schema import FORMAT, ROLES, Invocation, WorldModelEntry
from dynplan.world_parts import RunKind
from dynplan.worlds.minigrid import WORLD
from dynplan.worlds.minigrid.agent import AGENT_START_POSE, Outcome, step
from dynplan.worlds.minigrid.grid import MiniGridConfig, record_world

#: The techniques a row may name (`dynplan.worlds.minigrid.evaluation.TECHNIQUES`).
TECHNIQUE_NAMES = ("oracle", "walk", "stand_still", "constant_velocity", "random")
#: An action's letter in a row's run-length encoded actions, by action (0 turn left, 1 turn right, 2 forward).
LETTERS = "LRF"
RUN = re.compile(r"([LRF])([1-9][0-9]*)")
OUTCOMES = ("goal", "death", "timeout")


def encode_actions(actions: Iterable[int]) -> str:
    """Actions run-length encoded: each action's letter and how many steps in a row."""
    return "".join(f"{LETTERS[a]}{sum(1 for _ in run)}" for a, run in itertools.groupby(int(a) for a in actions))


def decode_actions(encoded: str) -> list[int]:
    """The actions a row's `encode_actions` string holds, one a step."""
    return [LETTERS.index(letter) for letter, count in RUN.findall(encoded) for _ in range(int(count))]


Text = Annotated[str, Field(min_length=1)]


class _Strict(BaseModel):
    model_config = ConfigDict(frozen=True, strict=True, extra="forbid", allow_inf_nan=False)


class Settings(_Strict):
    """What every row of a run depends on besides its case: the room and the search."""

    size: Annotated[int, Field(ge=5, le=64)]
    obstacles: Annotated[int, Field(ge=1, le=64)]
    steps: Annotated[int, Field(ge=1, le=100_000)]
    horizon: Annotated[int, Field(ge=1, le=8)]
    risk: Annotated[float, Field(ge=0.0, le=100.0)]
    samples: Annotated[int, Field(ge=1, le=4096)]


class MiniGridManifest(_Strict):
    """A MiniGrid run's `manifest.json`."""

    format: Literal[FORMAT]
    name: Annotated[str, Field(pattern=r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,99}$")]
    role: Literal[ROLES]
    world: Literal["minigrid-v1"]
    settings: Settings
    world_models: dict[Text, WorldModelEntry]
    invocations: list[Invocation]


class MiniGridRow(_Strict):
    """One line of a MiniGrid run's `episodes.jsonl`."""

    technique: Literal[TECHNIQUE_NAMES]
    model: Text | None
    seed: Annotated[int, Field(ge=0, le=2**62)]
    outcome: Literal[OUTCOMES]
    steps: Annotated[int, Field(ge=1, le=100_000)]
    decision_ms: Annotated[float, Field(ge=0.0)]
    actions: Annotated[str, Field(pattern=r"^([LRF][1-9][0-9]*)+$")]
    code_version: Text

    @model_validator(mode="after")
    def _one_action_a_step(self) -> MiniGridRow:
        played = sum(int(count) for _, count in RUN.findall(self.actions))
        if played != self.steps:
            raise ValueError(f"holds {played} actions for its {self.steps} steps")
        return self


RUNS = RunKind(
    world=WORLD.id,
    manifest_schema=MiniGridManifest,
    row_schema=MiniGridRow,
    case_keys=("technique", "model", "seed"),
    provenance_keys=(),
    result_keys=("outcome", "steps", "decision_ms", "actions", "code_version"),
    expected=lambda manifest, case: {},
)


def replayed(row: Mapping, settings: Mapping) -> tuple[str, int]:
    """How `row`'s actions end when played again from the start of its room (recorded from its seed with the run's
    settings), and after how many steps (actions past the end are not played)."""
    config = MiniGridConfig(size=settings["size"], obstacles=settings["obstacles"], steps=settings["steps"])
    frames = record_world(config, row["seed"]).frames
    pose, outcome, t = AGENT_START_POSE, Outcome.RUNNING, 0
    for action in decode_actions(row["actions"]):
        if outcome != Outcome.RUNNING or t >= len(frames) - 1:
            break
        pose, outcome = step(pose, action, frames[t], frames[t + 1])
        t += 1
    ended = Outcome.TIMEOUT if outcome == Outcome.RUNNING and t == len(frames) - 1 else outcome
    return ended.name.lower(), t


def replay_check(row: Mapping, settings: Mapping) -> str | None:
    """None when `row`'s actions, played again in its room, end as it says after its steps; else what differs."""
    outcome, steps = replayed(row, settings)
    if (outcome, steps) == (row["outcome"], row["steps"]):
        return None
    return f"its actions replay to {outcome} after {steps} steps; the row says {row['outcome']} after {row['steps']}"
