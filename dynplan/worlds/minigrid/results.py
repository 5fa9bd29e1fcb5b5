"""MiniGrid's runs in the results store (`dynplan.evaluation.store`, the same for every world): what a manifest and
a row hold, and the check that plays a row's recorded actions in its room again.

    <root>/runs/<run>/manifest.json   role, world `minigrid-v1`, the room's and the search's settings, every
                                      command that played the run
    <root>/runs/<run>/episodes.jsonl  one row per episode: its case (technique, world model, seed), how it ended,
                                      its steps, median decision ms, the actions, the code and (learned rows) the
                                      SHA-256 of the world model's weights

The actions are run-length encoded (`L2F5R1…`: L turn left, R turn right, F forward, each with how many steps in a
row): the room is recorded from its seed, so a row's outcome and steps follow from its seed and actions alone.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Annotated, Literal

from pydantic import Field, model_validator

from dynplan.evaluation.store import expected_weights
from dynplan.evaluation.store_schema import FORMAT, ROLES, Invocation, RunLengthActions, StrictSchema, WorldModelEntry
from dynplan.world_parts import RunKind
from dynplan.worlds.minigrid import WORLD
from dynplan.worlds.minigrid.agent import AGENT_START_POSE, Outcome, step
from dynplan.worlds.minigrid.grid import MiniGridConfig, record_world

#: The techniques a row may name (`dynplan.worlds.minigrid.evaluation.TECHNIQUES`); `learnedS` plans against S
#: futures the world model samples.
TECHNIQUE_NAMES = ("oracle", "walk", "learned10", "learned5", "learned1", "stand_still", "constant_velocity", "random")
#: The learned techniques, by the futures each samples a decision.
LEARNED_SAMPLES = {"learned10": 10, "learned5": 5, "learned1": 1}
#: A row's actions run-length encoded, a letter an action (L turn left, R turn right, F forward).
ACTIONS_CODE = RunLengthActions("LRF")
encode_actions, decode_actions = ACTIONS_CODE.encode, ACTIONS_CODE.decode
OUTCOMES = ("goal", "death", "timeout")


Text = Annotated[str, Field(min_length=1)]


class Settings(StrictSchema):
    """What every row of a run depends on besides its case: the room and the search."""

    size: Annotated[int, Field(ge=5, le=64)]
    obstacles: Annotated[int, Field(ge=1, le=64)]
    steps: Annotated[int, Field(ge=1, le=100_000)]
    horizon: Annotated[int, Field(ge=1, le=8)]
    risk: Annotated[float, Field(ge=0.0, le=100.0)]
    samples: Annotated[int, Field(ge=1, le=4096)]


class MiniGridManifest(StrictSchema):
    """A MiniGrid run's `manifest.json`."""

    format: Literal[FORMAT]
    name: Annotated[str, Field(pattern=r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,99}$")]
    role: Literal[ROLES]
    world: Literal["minigrid-v1"]
    settings: Settings
    world_models: dict[Text, WorldModelEntry]
    invocations: list[Invocation]


class MiniGridRow(StrictSchema):
    """One line of a MiniGrid run's `episodes.jsonl`."""

    technique: Literal[TECHNIQUE_NAMES]
    model: Text | None
    seed: Annotated[int, Field(ge=0, le=2**62)]
    outcome: Literal[OUTCOMES]
    steps: Annotated[int, Field(ge=1, le=100_000)]
    decision_ms: Annotated[float, Field(ge=0.0)]
    actions: Annotated[str, Field(pattern=ACTIONS_CODE.pattern)]
    code_version: Text
    world_model_sha256: Text | None = None

    @model_validator(mode="after")
    def _one_action_a_step(self) -> MiniGridRow:
        played = ACTIONS_CODE.steps(self.actions)
        if played != self.steps:
            raise ValueError(f"holds {played} actions for its {self.steps} steps")
        learned = self.technique in LEARNED_SAMPLES
        if learned != (self.model is not None) or learned != (self.world_model_sha256 is not None):
            need = "needs a model and its world_model_sha256" if learned else "takes no model"
            raise ValueError(f"technique {self.technique!r} {need}")
        return self


RUNS = RunKind(
    world=WORLD.id,
    manifest_schema=MiniGridManifest,
    row_schema=MiniGridRow,
    case_keys=("technique", "model", "seed"),
    provenance_keys=("world_model_sha256",),
    result_keys=("outcome", "steps", "decision_ms", "actions", "code_version"),
    expected=expected_weights,
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
