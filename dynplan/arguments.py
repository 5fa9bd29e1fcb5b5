"""Arguments of the public API checked against their annotations before any work, as configs are checked.

`@checked` reads a function's annotations (the first time it is called) and refuses, in one `ArgumentError` line
naming the function, the parameter and the value, an argument of the wrong kind — a bool where an int or a float is
taken, a string where a number is, a float where an int is, an object of another class — a number outside its
`Bounds`, and an array of another number of dimensions, shape or kind of number than its `Array` says, or holding a
NaN or an infinity where it must not. Every checked function is listed in `CHECKED`, so the hostile-input harness
draws bad values for each of its parameters from the same annotations.

    @checked
    def chicken_step(chicken: Chicken, action: Annotated[int, Bounds(0, 2)],
                     before: Annotated[np.ndarray, Array(shape=(154, 152))], ...) -> ...
"""

from __future__ import annotations

import functools
import inspect
import math
import types
import typing
from collections.abc import Callable
from dataclasses import dataclass
from typing import Annotated, Any, Literal, TypeVar, Union, get_args, get_origin

import numpy as np

from dynplan.cli import InputError


class ArgumentError(InputError, TypeError):
    """An argument of a public function that its annotation refuses; the message names the function, the parameter,
    the value and what it takes. A `TypeError` and a `ValueError` both, as Python's own would be."""


@dataclass(frozen=True)
class Bounds:
    """The closed range a number must lie in (None: unbounded on that side); NaN lies in none."""

    lo: float | None = None
    hi: float | None = None

    def problem(self, value: float) -> str | None:
        if math.isnan(value):  # a Python or a numpy NaN
            return "NaN is no number"
        if (self.lo is None or value >= self.lo) and (self.hi is None or value <= self.hi):
            return None
        return f"valid range [{'-inf' if self.lo is None else self.lo}, {'inf' if self.hi is None else self.hi}]"


@dataclass(frozen=True)
class Array:
    """What an array argument must be: its number of dimensions (or any of several), its shape (None for a free
    axis), the kind of its numbers ("u" unsigned, "i" integer, "f" float, "b" bool; any of those given) and whether
    it may hold a NaN or an infinity."""

    ndim: int | tuple[int, ...] | None = None
    shape: tuple[int | None, ...] | None = None
    kinds: str = "uifb"
    finite: bool = True

    def problem(self, value: np.ndarray) -> str | None:
        ndims = (self.ndim,) if isinstance(self.ndim, int) else self.ndim or ()
        if self.shape is not None:
            ndims = (len(self.shape),)
        if ndims and value.ndim not in ndims:
            return f"an array of {value.ndim} dimensions; it takes {' or '.join(map(str, ndims))}"
        if self.shape is not None and any(
            s is not None and s != v for s, v in zip(self.shape, value.shape, strict=True)
        ):
            wanted = "(" + ", ".join("any" if s is None else str(s) for s in self.shape) + ")"
            return f"an array of shape {value.shape}; it takes {wanted}"
        if value.dtype.kind not in self.kinds:
            return f"an array of {value.dtype}; it takes {' or '.join(_KIND_NAMES[k] for k in self.kinds)}"
        if self.finite and value.dtype.kind == "f" and not np.isfinite(value).all():
            return "an array holding NaN or infinity"
        return None


_KIND_NAMES = {"u": "unsigned integers", "i": "integers", "f": "floats", "b": "bools"}

#: Every function checked by `checked`, for the harness that draws bad arguments for each.
CHECKED: list[Callable] = []

F = TypeVar("F", bound=Callable[..., Any])


def union_members(annotation: Any) -> list[tuple[Any, tuple]]:
    """(type, its Annotated metadata) of each member of a union annotation."""
    metadata: tuple = ()
    if get_origin(annotation) is Annotated:
        annotation, *rest = get_args(annotation)
        metadata = tuple(rest)
    if get_origin(annotation) in (Union, types.UnionType):
        return [(t, metadata + m) for option in get_args(annotation) for t, m in union_members(option)]
    return [(annotation, metadata)]


def _fits(value: Any, kind: Any) -> bool:
    """Whether `value` is of `kind` as it is, with no coercion: a bool is no number, a float no int."""
    if kind is Any:
        return True
    if kind is None or kind is type(None):
        return value is None
    if kind is bool:
        return isinstance(value, bool | np.bool_)
    if kind is int:
        return isinstance(value, int | np.integer) and not isinstance(value, bool)
    if kind is float:
        return isinstance(value, int | float | np.integer | np.floating) and not isinstance(value, bool)
    if get_origin(kind) is Literal:
        return any(type(value) is type(option) and value == option for option in get_args(kind))
    origin = get_origin(kind) or kind
    return not isinstance(origin, type) or isinstance(value, origin)


def _name(kind: Any) -> str:
    if kind is type(None) or kind is None:
        return "None"
    if get_origin(kind) is Literal:
        return " or ".join(map(repr, get_args(kind)))
    origin = get_origin(kind) or kind
    name = str(getattr(origin, "__name__", origin))
    article = "an" if name[:1].lower() in "aeiou" else "a"
    return {int: "an integer", float: "a number", bool: "true or false", str: "a string"}.get(
        origin, f"{article} {name}"
    )


def problem(value: Any, annotation: Any) -> str | None:
    """Why `annotation` refuses `value` (None: it takes it)."""
    options = union_members(annotation)
    fitting = [(kind, metadata) for kind, metadata in options if _fits(value, kind)]
    if not fitting:
        taken = " or ".join(dict.fromkeys(_name(kind) for kind, _ in options))
        kind = type(value).__name__
        return f"{'an' if kind[:1] in 'aeiouAEIOU' else 'a'} {kind}, not {taken}"
    why = None
    for kind, metadata in fitting:  # a union's constraints bind the members they are about
        checks = [m for m in metadata if isinstance(m, Array if kind is np.ndarray else Bounds)]
        checks = checks if kind in (int, float, np.ndarray) else []
        why = next((w for w in (m.problem(value) for m in checks) if w), None)
        if why is None:
            return None
    return why


def shown(value: Any, limit: int = 60) -> str:
    """A value as a message shows it: its repr, shortened; an array by its shape and type."""
    if isinstance(value, np.ndarray):
        return f"array(shape={value.shape}, dtype={value.dtype})"
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 1] + "…"


def checked(function: F) -> F:
    """`function` with every annotated argument checked (`problem`) before it runs."""

    @functools.wraps(function)
    def wrapper(*args, **kwargs):
        why = refusal(wrapper, *args, **kwargs)
        if why:
            raise ArgumentError(why)
        return function(*args, **kwargs)

    CHECKED.append(wrapper)
    return typing.cast(F, wrapper)


def refusal(function: Callable, /, *args, **kwargs) -> str | None:
    """The line a `checked` function refuses these arguments with (None: it takes them), without running it."""
    inner = inspect.unwrap(function)
    bound = _signature(inner).bind(*args, **kwargs)
    hints = _hints(inner)
    for name, value in bound.arguments.items():
        why = problem(value, hints[name]) if name in hints else None
        if why:
            return f"{inner.__qualname__}: {name}={shown(value)} is invalid ({why})"
    return None


@functools.cache
def _signature(function: Callable) -> inspect.Signature:
    return inspect.signature(function)


@functools.cache
def _hints(function: Callable) -> dict[str, Any]:
    """The annotations of `function`'s parameters, resolved, with their metadata."""
    hints = typing.get_type_hints(function, include_extras=True)
    hints.pop("return", None)
    return hints
