"""Prefect's `flow` and `task` decorators, deferred: a command's `--help` and a usage error answer before Prefect
(about a second to import) is loaded.

Where Prefect is already loaded when a flow module is imported (a Prefect worker or engine loading a deployment's
flow, `flows.serve`, the tests), the decorators are Prefect's own, so every flow is a real `prefect.Flow`. Elsewhere a
decorated function becomes a `Deferred`, which builds the Prefect flow or task on first use and forwards every call
and attribute to it (`.map`, `.with_options`, `.to_deployment`, …). `NO_CACHE` stands for Prefect's policy of the
same name.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from functools import cached_property
from typing import Any

#: Stands for `prefect.cache_policies.NO_CACHE` in a deferred decorator's options.
NO_CACHE = "NO_CACHE"


def _built(kind: str, fn: Callable, options: dict[str, Any]) -> Any:
    """The Prefect flow or task (`kind`) of `fn` with `options`."""
    import prefect
    from prefect import cache_policies

    if options.get("cache_policy") == NO_CACHE:
        options = {**options, "cache_policy": cache_policies.NO_CACHE}
    return getattr(prefect, kind)(**options)(fn)


class Deferred:
    """A Prefect flow or task built from `fn` when first used."""

    def __init__(self, kind: str, fn: Callable, options: dict[str, Any]) -> None:
        self._kind, self._fn, self._options = kind, fn, options
        self.__doc__, self.__name__, self.__wrapped__ = fn.__doc__, fn.__name__, fn

    @cached_property
    def built(self) -> Any:
        """The Prefect object itself."""
        return _built(self._kind, self._fn, self._options)

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        return self.built(*args, **kwargs)

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__") or name in ("_kind", "_fn", "_options"):
            raise AttributeError(name)
        return getattr(self.built, name)

    def __repr__(self) -> str:
        return f"Deferred({self._kind} {self.__name__})"


def _decorator(kind: str, options: dict[str, Any]) -> Callable[[Callable], Any]:
    def decorate(fn: Callable) -> Any:
        if "prefect" in sys.modules:
            return _built(kind, fn, options)
        return Deferred(kind, fn, options)

    return decorate


def flow(**options: Any) -> Callable[[Callable], Any]:
    """`prefect.flow(**options)`, deferred where Prefect is not loaded yet."""
    return _decorator("flow", options)


def task(**options: Any) -> Callable[[Callable], Any]:
    """`prefect.task(**options)`, deferred where Prefect is not loaded yet."""
    return _decorator("task", options)
