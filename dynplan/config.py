"""Base for dynplan's configuration objects: frozen pydantic models whose errors read as one clear line.

A bad value names the field, the value given and the field's valid range; an unknown key is named together
with the valid keys. Configs serialise to plain dicts (`model_dump`) for Prefect parameters, cache keys and
log metadata.

A field added after configs were first hashed into cache keys and checkpoints lists itself in `_neutral` with
the value that means "as before": it is left out of the dict while it has that value, so existing keys and
checkpoints stay valid.
"""

from __future__ import annotations

import hashlib
import json
from typing import Any, ClassVar

from pydantic import BaseModel, ConfigDict, ValidationError, model_serializer
from pydantic.fields import FieldInfo

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
            what = f"{'.'.join(map(str, loc))}={err.get('input')!r} is invalid ({err['msg'].lower()})"
            if field is not None:
                rng = valid_range(field)
                what += f"; valid range {rng}" if rng else ""
                what += f" — {field.description}" if field.description else ""
            problems.append(what)
    return f"{cls.__name__}: " + "; ".join(problems)


class Config(BaseModel):
    """Frozen, strict-keyed config whose construction errors are `ConfigError`s."""

    model_config = ConfigDict(frozen=True, extra="forbid")
    _neutral: ClassVar[dict[str, Any]] = {}

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
