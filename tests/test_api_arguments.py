"""The public API refuses bad arguments in one line, drawn from the API's own annotations: for every function
`dynplan.arguments.checked` guards and every field of every config, bad values of each annotation's kind — a bool
for a number, a string for a number, a float for an int, NaN, infinities, values past each bound, a huge int,
arrays of another shape, number of dimensions or kind of number, or holding NaN, objects of another class — each
refused by name, never accepted and never an AttributeError or IndexError from inside."""

from __future__ import annotations

import math
import typing
from typing import Any, Literal, get_origin

import numpy as np
import pytest

import dynplan.data.collect
import dynplan.env.road
import dynplan.evaluation.cases
import dynplan.evaluation.protocol
import dynplan.models.caution
import dynplan.models.configs
import dynplan.models.world_model
import dynplan.pipeline.presets
import dynplan.planning.config
import dynplan.training.budget
import dynplan.worlds.freeway.commands
import dynplan.worlds.freeway.game
import dynplan.worlds.freeway.presets
import dynplan.worlds.freeway.search
import dynplan.worlds.minigrid.commands
import dynplan.worlds.minigrid.grid
import dynplan.worlds.minigrid.presets
import dynplan.worlds.minigrid.search
import dynplan.worlds.road.commands
import dynplan.worlds.road.evaluate
from dynplan.arguments import CHECKED, ArgumentError, Array, Bounds, refusal, union_members
from dynplan.config import Config, ConfigError
from dynplan.worlds.freeway.game import LANE_HEIGHT, LANE_WIDTH, Chicken, FreewayGame, chicken_step, lane_frame
from dynplan.worlds.minigrid.grid import MiniGridConfig
from tests.hostile import OUTCOMES

_FRAME = np.full((LANE_HEIGHT, LANE_WIDTH), 6, np.uint8)
#: A call each checked function takes (`self` of a method is any object: it has no annotation).
VALID: dict[str, dict[str, Any]] = {
    "plan_episode": {"world": 5},
    "generate_world": {},
    "record_world": {"config": MiniGridConfig(), "seed": 0},
    "record_episode": {"out_dir": "never-written", "seed": 0},
    "load_world_model": {},
    "FreewayGame.step": {"self": object(), "action": 0},
    "lane_frame": {"screen": np.zeros((210, 160), np.uint8)},
    "chicken_step": {"chicken": Chicken(6), "action": 0, "before": _FRAME, "after": _FRAME},
    "extrapolated": {"observed": np.stack([_FRAME] * 3), "k": 4},
    "record_mode": {"mode": 0},
}


def _number_draws(kind: type, bounds: list[Bounds]) -> list[Any]:
    """Bad values for an int or a float: other kinds, NaN and infinities, past each bound."""
    draws: list[Any] = [True, "1", float("nan"), float("inf"), -float("inf"), [1]]
    if kind is int:
        draws += [1.5, 2.0, 2**70]
    for bound in bounds:
        if bound.lo is not None:
            draws.append(kind(bound.lo) - 1 if kind is int else bound.lo - 0.5)
        if bound.hi is not None:
            draws.append(kind(bound.hi) + 1 if kind is int else bound.hi + 0.5)
    return draws


def _array_draws(spec: Array) -> list[Any]:
    """Bad arrays: a list for an array, another number of dimensions, shape or kind of number, NaN inside."""
    ndim = spec.ndim if isinstance(spec.ndim, int) else max(spec.ndim or (2,))
    shape = tuple(3 if s is None else s for s in spec.shape) if spec.shape else (4,) * ndim
    draws: list[Any] = [np.zeros(shape).tolist(), np.zeros(()), np.zeros((*shape, 2)), np.zeros(shape, complex)]
    draws.append(np.zeros(shape, "U1"))
    if spec.shape and spec.shape[-1] is not None:
        draws.append(np.zeros((*shape[:-1], shape[-1] + 1), np.uint8))
    if spec.finite and "f" in spec.kinds:
        draws.append(np.full(shape, np.nan))
    if "f" not in spec.kinds:
        draws.append(np.zeros(shape, np.float32))
    return draws


def draws(annotation: Any) -> list[Any]:
    """Values `annotation` must refuse, of every kind it does not take."""
    members = union_members(annotation)
    kinds = {kind for kind, _ in members}
    found: list[Any] = [object(), b"bytes"]
    if type(None) not in kinds and None not in kinds:
        found.append(None)
    for kind, metadata in members:
        if kind in (int, float):
            found += _number_draws(kind, [m for m in metadata if isinstance(m, Bounds)])
        elif kind is np.ndarray:
            found += [a for m in metadata if isinstance(m, Array) for a in _array_draws(m)]
        elif kind is bool or get_origin(kind) is Literal:
            found += [1, "yes"]
        elif kind is str:
            found += [5, True]
        elif isinstance(kind, type) and kind is not type(None):  # an object of the class: no number or string is
            found += [
                v for v, k in ((3, int), ("text", str), (1.5, float)) if not kinds & {k, float if k is int else k}
            ]
    return found


def _cases() -> list[tuple[str, str, Any]]:
    by_name = {f.__qualname__: f for f in CHECKED}
    assert set(VALID) <= set(by_name), set(VALID) - set(by_name)
    cases = []
    for name, function in by_name.items():
        hints = typing.get_type_hints(function, include_extras=True)
        for parameter, annotation in hints.items():
            if parameter != "return":
                cases += [(name, parameter, value) for value in draws(annotation)]
    return cases


CASES = _cases()


def _accepted(value: Any, annotation: Any) -> bool:
    """Whether `value` is one the annotation takes after all (e.g. an int for a float within its bounds)."""
    return any(
        kind is float and isinstance(value, int) and not isinstance(value, bool) and math.isfinite(value)
        for kind, _ in union_members(annotation)
    ) and not any(isinstance(m, Bounds) and m.problem(value) for _, ms in union_members(annotation) for m in ms)


def test_every_checked_function_has_a_valid_call_and_takes_it():
    for function in CHECKED:
        assert function.__qualname__ in VALID, f"{function.__qualname__}: no valid call in VALID"
        assert refusal(function, **VALID[function.__qualname__]) is None, function.__qualname__
    assert len(CASES) >= 300


@pytest.mark.parametrize("name", sorted(VALID))
def test_every_bad_argument_is_refused_in_one_line_naming_it(name):
    """Each function's drawn cases in one test (a test item each would cost more than the checks themselves)."""
    function = next(f for f in CHECKED if f.__qualname__ == name)
    hints = typing.get_type_hints(function, include_extras=True)
    taken, badly = [], []
    for _, parameter, value in (case for case in CASES if case[0] == name):
        if _accepted(value, hints[parameter]):
            continue
        why = refusal(function, **{**VALID[name], parameter: value})
        OUTCOMES[("api arguments", "refused" if why else "accepted")] += 1
        if why is None:
            taken.append(f"{parameter}={value!r}")
        elif "\n" in why or not why.startswith(f"{name}: {parameter}="):
            badly.append(why)
    assert not taken and not badly, (taken, badly)


def test_a_checked_call_raises_before_any_work():
    """The guard runs in the call itself: an ArgumentError (a TypeError and a ValueError both) naming it."""
    for call, line in [
        (lambda: FreewayGame.step(object(), True), "FreewayGame.step: action=True"),
        (lambda: chicken_step(Chicken(6), 3, _FRAME, _FRAME), "chicken_step: action=3"),
        (lambda: chicken_step(Chicken(-50), 0, _FRAME, _FRAME), "chicken_step: chicken=Chicken(y=-50"),
        (lambda: lane_frame(np.zeros((10, 10), np.uint8)), "lane_frame: screen of shape (10, 10)"),
        (lambda: dynplan.evaluation.protocol.plan_episode(3.5), "plan_episode: world=3.5"),
        (lambda: dynplan.evaluation.protocol.plan_episode(5, "oracle"), "plan_episode: spec='oracle'"),
        (lambda: dynplan.worlds.freeway.game.extrapolated(_FRAME[None], 3), "extrapolated: observed holds 1"),
    ]:
        with pytest.raises(ArgumentError) as raised:
            call()
        assert str(raised.value).startswith(line) and isinstance(raised.value, TypeError | ValueError), raised.value


def _configs() -> list[type[Config]]:
    """Every config class of the library (its modules imported by this file and the harness's imports)."""
    found, todo = [], list(Config.__subclasses__())
    while todo:
        cls = todo.pop()
        found.append(cls)
        todo += cls.__subclasses__()
    return sorted({c for c in found if c.__module__.startswith("dynplan.")}, key=lambda c: c.__qualname__)


def _field_cases() -> list[tuple[type[Config], str, Any]]:
    cases = []
    for cls in _configs():
        try:
            cls()
        except ConfigError:  # a config with required fields: its fields are drawn where it is built whole
            continue
        for name, field in cls.model_fields.items():
            annotation = field.annotation
            bounds = [
                Bounds(getattr(m, "ge", None), getattr(m, "le", None))
                for m in field.metadata
                if getattr(m, "ge", None) is not None or getattr(m, "le", None) is not None
            ]
            scalar = {kind for kind, _ in union_members(annotation)}
            if scalar & {int, float}:
                kind = int if int in scalar and float not in scalar else float
                values = [v for v in _number_draws(kind, bounds) if not isinstance(v, list) and v != 2.0]  # 2.0 is 2
            elif scalar == {bool}:
                values = [1, "yes", "true"]
            else:
                continue
            cases += [(cls, name, value) for value in values if not _accepted(value, annotation)]
    return cases


FIELD_CASES = _field_cases()


def test_the_config_harness_draws_from_every_config():
    assert len(_configs()) >= 20 and len(FIELD_CASES) >= 600, (len(_configs()), len(FIELD_CASES))


@pytest.mark.parametrize("cls", sorted({c for c, _, _ in FIELD_CASES}, key=lambda c: c.__qualname__),
                         ids=lambda c: c.__qualname__)  # fmt: skip
def test_every_bad_config_value_is_refused_in_one_line_naming_its_field(cls):
    taken, badly = [], []
    for name, value in ((n, v) for c, n, v in FIELD_CASES if c is cls):
        try:
            cls(**{name: value})
        except ConfigError as error:
            OUTCOMES[("config fields", "refused")] += 1
            message = str(error)
            if "\n" in message or not message.startswith(f"{cls.__name__}: ") or f"{name}=" not in message:
                badly.append(message)
        else:
            taken.append(f"{name}={value!r}")
    assert not taken and not badly, (taken, badly)
