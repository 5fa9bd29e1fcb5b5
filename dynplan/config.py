"""Base for dynplan's configuration objects: frozen pydantic models whose errors read as one clear line.

A bad value names the field, the value given and the field's valid range; an unknown key is named together
with the valid keys. Scalars are taken as they are, never coerced: a bool is not a number, a string is neither a
number nor a bool, and a number is not a bool (`coercion`; an int is a number, and 2.0 an int), here and in every
`--set` and config file. Configs serialise to plain dicts (`model_dump`) for Prefect parameters, cache keys and
log metadata.

A field added after configs were first hashed into cache keys and checkpoints lists itself in `_neutral` with
the value that means "as before": it is left out of the dict while it has that value, so existing keys and
checkpoints stay valid.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar, get_args, get_origin

from pydantic import BaseModel, ConfigDict, ValidationError, model_serializer, model_validator
from pydantic.fields import FieldInfo

from dynplan.arguments import union_members
from dynplan.cli import InputError


class ConfigError(InputError):
    """A configuration value is invalid; the message names the field and what it accepts."""


def valid_range(field: FieldInfo) -> str:
    """Interval notation for a field's numeric bounds, e.g. "[0, 100]" or "(0, 8]"; "" if unbounded."""
    lo = hi = None
    lo_open = hi_open = False
    for bound in field.metadata:
        for name in ("ge", "gt", "le", "lt"):
            value = getattr(bound, name, None)
            if value is None:
                continue
            if name in ("ge", "gt"):
                lo, lo_open = value, name == "gt"
            else:
                hi, hi_open = value, name == "lt"
    if lo is None and hi is None:
        return ""
    left = "(" if lo_open or lo is None else "["
    right = ")" if hi_open or hi is None else "]"
    return f"{left}{'-inf' if lo is None else lo}, {'inf' if hi is None else hi}{right}"


def field_help(cls: type[BaseModel], name: str, default: str | None = None) -> str:
    """A command-line help text from a config field: its description, valid range and default (`default`
    overrides how the default is told, e.g. "each configuration's own")."""
    field = cls.model_fields[name]
    rng = valid_range(field)
    told = default if default is not None else repr(field.default)
    return f"{field.description or name}" + (f"; valid range {rng}" if rng else "") + f" (default: {told})"


def describe(cls: type[BaseModel], error: ValidationError) -> str:
    """Turn a pydantic ValidationError into one readable sentence per problem."""
    problems = []
    for err in error.errors():
        loc = err["loc"]
        if err["type"] == "extra_forbidden":
            problems.append(f"unknown key {loc[0]!r} (valid keys: {', '.join(cls.model_fields)})")
        elif not loc:  # a model-level check
            problems.append(str(err["msg"]).removeprefix("Value error, "))
        else:
            field = cls.model_fields.get(str(loc[0]))
            what = (
                f"{'.'.join(map(str, loc))}={err.get('input')!r} is invalid ({err['msg'][:1].lower() + err['msg'][1:]})"
            )
            if field is not None:
                rng = valid_range(field)
                what += f"; valid range {rng}" if rng else ""
                what += f" — {field.description}" if field.description else ""
            problems.append(what)
    return f"{cls.__name__}: " + "; ".join(problems)


#: What a value of each scalar kind is called, for the message that refuses it.
_KINDS = {bool: "true or false", int: "an integer", float: "a number", type(None): "null"}


def coercion(value: Any, annotation: Any) -> str | None:
    """Why pydantic would coerce `value` to fit `annotation` instead of taking it as it is — a bool read as a number,
    a string as a number or a bool, a number as a bool — in a field of scalars (or of tuples, lists or mappings of
    them); None when the value is taken as it is, or the annotation's own validation decides."""
    options = [kind for kind, _ in union_members(annotation)]
    if len(options) == 1 and isinstance(value, list | tuple) and get_origin(options[0]) in (tuple, list, Sequence):
        inner = [a for a in get_args(options[0]) if a is not Ellipsis]
        items = inner * len(value) if len(inner) == 1 else inner
        found = (coercion(item, a) for item, a in zip(value, items, strict=False))
        return next((f"item {i}: {why}" for i, why in enumerate(found) if why), None)
    if len(options) == 1 and isinstance(value, dict) and get_origin(options[0]) in (dict, Mapping):
        found = ((key, coercion(item, get_args(options[0])[-1])) for key, item in value.items())
        return next((f"key {key!r}: {why}" for key, why in found if why), None)
    if not options or not all(option in _KINDS for option in options):
        return None  # a string, a path, a literal, a config…: its own validation decides
    kind = bool if isinstance(value, bool) else int if isinstance(value, int) else type(value)
    numbers = kind in (int, float) and bool({int, float} & set(options))  # an int a float; pydantic: 2.0 an int
    if kind in options or numbers or kind not in (bool, int, float, str):
        return None
    expected = " or ".join(_KINDS[option] for option in options)
    return f"a {kind.__name__} {value!r} is not {expected}"


class Config(BaseModel):
    """Frozen, strict-keyed config whose construction errors are `ConfigError`s; scalars are never coerced."""

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)
    _neutral: ClassVar[dict[str, Any]] = {}

    @model_validator(mode="before")
    @classmethod
    def _taken_as_given(cls, data: Any) -> Any:
        """Refuse a value pydantic would coerce (`coercion`), naming the field and its valid range."""
        if not isinstance(data, dict):
            return data
        for name, value in data.items():
            field = cls.model_fields.get(name)
            why = None if field is None else coercion(value, field.annotation)
            if why:
                rng = valid_range(field)
                where = f"; valid range {rng}" if rng else ""
                raise ValueError(f"{name}={value!r} is invalid ({why}){where}")
        return data

    @model_serializer(mode="wrap")
    def _omit_neutral(self, handler):
        data = handler(self)
        for name, value in self._neutral.items():
            if name in data and data[name] == value:
                del data[name]
        return data

    def __init__(self, **data: Any) -> None:
        try:
            super().__init__(**data)
        except ValidationError as error:
            raise ConfigError(describe(type(self), error)) from None

    @classmethod
    def from_dict(cls, values: dict | None = None, **overrides: Any):
        """Build from a plain dict (MCAP metadata, Prefect parameters) plus keyword overrides."""
        return cls(**{**(values or {}), **overrides})


def digest(*parts: Any) -> str:
    """A stable hex key of JSON-serialisable parts (configs, fingerprints, code versions)."""
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()
