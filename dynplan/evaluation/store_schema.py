"""The results store's schema: what a run's manifest and each row of its episodes hold (docs/formats.md §3).

Frozen, strict pydantic models: a number written as a string, a float where a count belongs, a missing field, an
unknown outcome or a negative step count is refused rather than read into a table (a manifest whose playouts are
"100" would otherwise make every row of its run stale, and vanish from the pages). The store validates on every
read and before every write; `first_problem` turns pydantic's report into one phrase and the place it concerns,
and `line_of` finds that place's line in a JSON document, so that a message names the file and the line.
"""

from __future__ import annotations

import itertools
import json
import math
import re
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Annotated, Any, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

FORMAT = "dynplan-run/1"
#: evaluation: counts in Table 1; validation: the validation episodes, where settings are chosen; candidate: the
#: evaluation episodes with weights or settings not committed; superseded: the evaluation of weights or settings
#: that are no longer the committed ones.
ROLES = ("evaluation", "validation", "candidate", "superseded")
OUTCOMES = ("goal", "timeout", "death")

Count = Annotated[int, Field(ge=0)]
Positive = Annotated[int, Field(ge=1)]
Seconds = Annotated[float, Field(ge=0.0)]
Text = Annotated[str, Field(min_length=1)]
#: The caution's fields (`dynplan.models.caution.Caution`) with its ranges; absent: off (a manifest may say null).
Occupancy = Annotated[float, Field(ge=0.0, lt=1.0)]
Margin = Annotated[int, Field(ge=0, le=4)]


def _setting(value: Any) -> Any:
    """A setting recorded by other code (docs/experiments.md): one JSON scalar, nothing nested."""
    if value is not None and not isinstance(value, str | int | float | bool):
        raise ValueError("is not a setting (a string, a number, true, false or null)")
    return value


Setting = Annotated[Any, AfterValidator(_setting)]


def _durations(values: list) -> list:
    """Per-decision milliseconds: finite numbers ≥ 0 (checked in one pass: a row holds hundreds, and every read of
    the store checks every row)."""
    for i, value in enumerate(values):
        if isinstance(value, bool) or not isinstance(value, int | float) or not (math.isfinite(value) and value >= 0):
            raise ValueError(f"has item {i} = {_shown(value)}, not a finite number ≥ 0")
    return values


Durations = Annotated[list, AfterValidator(_durations)]


class StrictSchema(BaseModel):
    """A record of the store: frozen, strict types (a bool is no int, a str no number), no other keys, finite."""

    model_config = ConfigDict(frozen=True, strict=True, extra="forbid", allow_inf_nan=False)


@dataclass(frozen=True)
class RunLengthActions:
    """A row's actions, run-length encoded: each action's letter (`letters[action]`) and how many steps in a row it
    was played (`U52N3D1…`), so an episode of thousands of steps is a short string."""

    letters: str

    @property
    def pattern(self) -> str:
        """What a row's encoded actions match: one or more letter-and-count runs."""
        return rf"^([{self.letters}][1-9][0-9]*)+$"

    def encode(self, actions: Iterable[int | str]) -> str:
        """Actions (indices, or their digits) encoded."""
        runs = itertools.groupby(int(a) for a in actions)
        return "".join(f"{self.letters[a]}{sum(1 for _ in run)}" for a, run in runs)

    def decode(self, encoded: str) -> list[int]:
        """The actions an encoded string holds, one a step."""
        return [self.letters.index(letter) for letter, count in self._runs(encoded) for _ in range(int(count))]

    def steps(self, encoded: str) -> int:
        """How many steps an encoded string holds."""
        return sum(int(count) for _, count in self._runs(encoded))

    def _runs(self, encoded: str) -> list[tuple[str, str]]:
        return re.findall(rf"([{self.letters}])([1-9][0-9]*)", encoded)


class RowSchema(StrictSchema):
    """One line of `episodes.jsonl`: the case, how its episode went, and its provenance. Any other key is a
    setting recorded by code that had it (part of the row's provenance), a JSON scalar."""

    model_config = ConfigDict(extra="allow")
    __pydantic_extra__: dict[str, Setting]

    technique: Text
    model: Text | None
    agent_speed: Annotated[float, Field(gt=0.0)]
    rollout_steps: Positive | None
    seed: Count
    outcome: Literal[OUTCOMES]
    steps: Count
    playouts: Positive
    log_sha256: Text
    # absent where they do not apply; present, never null (a null is a damaged value)
    world_model_sha256: Text = None
    occupancy: Occupancy = None
    margin: Margin = None
    decision_ms: Durations
    wall_s: Seconds
    code_version: Text = None

    @model_validator(mode="after")
    def _one_decision_a_step(self) -> RowSchema:
        """A step is one decision: an episode of `steps` steps timed each one (so a step count of 10**30 is no row)."""
        if len(self.decision_ms) != self.steps:
            raise ValueError(f"holds {len(self.decision_ms)} decision times for its {self.steps} steps")
        return self


class RecordedCaution(StrictSchema):
    """A world model's caution in a manifest: the settings that are on, and any of other code's (scalars)."""

    model_config = ConfigDict(extra="allow")
    __pydantic_extra__: dict[str, Setting]

    occupancy: Occupancy | None = None
    margin: Margin | None = None


class WorldModelEntry(StrictSchema):
    weights_sha256: Text
    weights: list[Text] = []
    caution: RecordedCaution = RecordedCaution()


class Invocation(StrictSchema):
    command: Text
    code_version: Text
    started: Text | None
    equivalent: Text | None = None


class ManifestSchema(StrictSchema):
    """A run's `manifest.json`."""

    format: Literal[FORMAT]
    name: Annotated[str, Field(pattern=r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,99}$")]
    role: Literal[ROLES]
    playouts: Positive
    episode_seeds: list[Count]
    log_sha256: dict[str, Text | None]
    world_models: dict[Text, WorldModelEntry]
    invocations: list[Invocation]

    @field_validator("log_sha256")
    @classmethod
    def _seeds_as_keys(cls, value: dict[str, str | None]) -> dict[str, str | None]:
        wrong = [key for key in value if not key.isdigit()]
        if wrong:
            raise ValueError(f"key {wrong[0]!r} is not a seed (the log's seed, in digits)")
        return value


#: How a pydantic error type reads after "field 'x' = value".
_REASONS = {
    "int_type": "is not an integer",
    "float_type": "is not a number",
    "finite_number": "is not a finite number",
    "string_type": "is not a string",
    "list_type": "is not a list",
    "dict_type": "is not an object",
    "model_type": "is not an object",
    "string_too_short": "is empty",
    "string_pattern_mismatch": "is not a valid name",
}


def _shown(value: Any, limit: int = 60) -> str:
    text = json.dumps(value) if isinstance(value, list | dict) else repr(value)
    return text if len(text) <= limit else text[: limit - 1] + "…"


def _phrase(error: dict) -> str:
    """One problem of a pydantic report as a phrase: "field 'steps' = 'abc' is not an integer"."""
    field = ".".join(map(str, error["loc"]))
    kind, ctx = error["type"], error.get("ctx") or {}
    if kind == "missing":
        return f"field {field!r} is missing"
    if kind == "extra_forbidden":
        return f"field {field!r} is unknown"
    if kind == "literal_error":
        reason = f"is not one of {ctx['expected']}"
    elif kind in _REASONS:
        reason = _REASONS[kind]
    elif kind == "value_error":  # the schema's own checks say what they found
        reason = str(ctx.get("error", error["msg"]))
        if not field:  # a check of the whole record: "holds 1 decision times for its 20 steps"
            return f"the record {reason}"
        if isinstance(error["input"], dict | list):
            return f"field {field!r} {reason}"
    else:  # a range: "should be greater than or equal to 1"
        reason = "is out of range (" + error["msg"].lower().removeprefix("input ") + ")"
    return f"field {field!r} = {_shown(error['input'])} {reason}"


def first_problem(schema: type[BaseModel], data: Any) -> tuple[tuple, str] | None:
    """None when `data` fits `schema`; else the first problem's place (its keys and indices) and one phrase
    saying what is wrong (with how many more problems there are)."""
    if not isinstance(data, dict):
        return (), f"is a JSON {type(data).__name__}, not an object"
    try:
        schema.model_validate(data)
    except ValidationError as error:
        errors = error.errors()
        more = f" (and {len(errors) - 1} more problem{'s' if len(errors) > 2 else ''})" if len(errors) > 1 else ""
        return tuple(errors[0]["loc"]), _phrase(errors[0]) + more
    return None


_DECODER = json.JSONDecoder()
_SPACE = re.compile(r"[ \t\n\r]*")


def _skip(text: str, pos: int, separator: str = "") -> int:
    """`pos` past white space and, if it is next, `separator` and the white space after it."""
    pos = _SPACE.match(text, pos).end()
    if separator and text.startswith(separator, pos):
        pos = _SPACE.match(text, pos + 1).end()
    return pos


def _member(text: str, pos: int, part: str | int) -> int | None:
    """Where the member `part` (an object's key or an array's index) of the JSON value at `pos` starts."""
    if text.startswith("{", pos):
        pos = _skip(text, pos + 1)
        while text.startswith('"', pos):
            key, pos = _DECODER.raw_decode(text, pos)
            pos = _skip(text, pos, ":")
            if key == part:
                return pos
            pos = _skip(text, _DECODER.raw_decode(text, pos)[1], ",")
    elif text.startswith("[", pos) and isinstance(part, int):
        pos = _skip(text, pos + 1)
        for _ in range(part):
            if text.startswith("]", pos):
                return None
            pos = _skip(text, _DECODER.raw_decode(text, pos)[1], ",")
        return None if text.startswith("]", pos) else pos
    return None


def line_of(text: str, place: tuple) -> int:
    """The line of the JSON document `text` where the value at `place` (keys and indices) starts; where a part of
    it is absent (a missing field), the line of the deepest part present."""
    pos = _skip(text, 0)
    for part in place:
        found = _member(text, pos, part)
        if found is None:
            break
        pos = found
    return text.count("\n", 0, pos) + 1
