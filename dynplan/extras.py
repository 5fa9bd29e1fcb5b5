"""Optional packages (pyproject's extras): importing one an option needs, or saying how to install it."""

from __future__ import annotations

from types import ModuleType

from dynplan.cli import InputError


class MissingExtra(InputError, RuntimeError):
    """The optional package an option needs is not installed."""


def install_hint(extra: str) -> str:
    """The command that installs extra `extra` into a checkout of dynplan."""
    return f"pip install -e '.[{extra}]'"


def require(module: str, extra: str, what: str) -> ModuleType:
    """`module`, imported; else a `MissingExtra` saying that `what` needs it and how to install `extra`."""
    try:
        return __import__(module, fromlist=["__name__"])  # through the import hook, which tests may stand in for
    except ImportError:
        raise MissingExtra(f"{what} needs the {module.split('.')[0]} package: {install_hint(extra)}") from None
