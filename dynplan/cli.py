"""What every command shares: a parser whose errors are one line, option types that declare their valid range, and a
runner that turns an error into one line and an interrupt into "interrupted" and exit status 130.

Each option declares what it takes — a `Bounded` number, a `dynplan.paths.PathArgument` path, or argparse choices —
so a bad value is refused while parsing, before any work, and a test can draw bad values from the declaration.
"""

from __future__ import annotations

import argparse
import ctypes
import errno
import math
import os
import re
import signal
import sys
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NoReturn, get_args

from dynplan.interrupts import interrupted_while_loading

if TYPE_CHECKING:
    from pydantic import BaseModel


_PR_SET_PDEATHSIG = 1  # prctl(2)


class InputError(ValueError):
    """An input a command or the API cannot use (a value, a path, a file's content); its message is one line naming
    it. `run_command` reports it as bad input (exit status 2); any other error is unexpected (exit status 1)."""


#: argparse's "argument --seed: " prefix, read as "--seed".
_ARGUMENT = re.compile(r"^argument ([^:]+): ?")


class CommandParser(argparse.ArgumentParser):
    """An ArgumentParser whose usage errors are one line (`prog: error: …`, exit status 2) with no usage block."""

    def error(self, message: str) -> NoReturn:
        match = _ARGUMENT.match(message)
        if match:  # "argument --seed: =-1 is invalid" → "--seed=-1 is invalid"
            rest = message[match.end() :].lstrip()
            name = match.group(1).split("/")[0]
            message = f"{name}{'' if rest.startswith('=') else ' '}{rest}"
        self.exit(2, f"{self.prog}: error: {message}\n")


@dataclass(frozen=True)
class Bounded:
    """An argparse `type` for a finite `kind` number between `low` and `high` (None: no bound), each bound included
    unless `open_low` / `open_high` says it is excluded."""

    kind: type = int
    low: float | None = None
    high: float | None = None
    open_low: bool = False
    open_high: bool = False

    def __call__(self, text: str) -> int | float:
        noun = "an integer" if self.kind is int else "a number"
        try:
            value = self.kind(text)
        except (TypeError, ValueError):
            raise argparse.ArgumentTypeError(f" {text!r} is not {noun}") from None
        if isinstance(value, float) and not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"={text} is invalid; it must be a finite number")
        if not self.contains(value):
            raise argparse.ArgumentTypeError(f"={text} is invalid; valid range {self.range}")
        return value

    def contains(self, value: float) -> bool:
        above = self.low is None or value > self.low or (value == self.low and not self.open_low)
        below = self.high is None or value < self.high or (value == self.high and not self.open_high)
        return above and below

    @property
    def range(self) -> str:
        left = "(" if self.open_low or self.low is None else "["
        right = ")" if self.open_high or self.high is None else "]"
        return f"{left}{'-inf' if self.low is None else self.low}, {'inf' if self.high is None else self.high}{right}"

    @property
    def __name__(self) -> str:
        return self.kind.__name__


def bounded(model: type[BaseModel], name: str) -> Bounded:
    """The `Bounded` type of a config field: its type and its bounds, as the config declares them (an exclusive bound
    of an integer field becomes the next integer)."""
    field = model.model_fields[name]
    kind = float if float in (field.annotation, *get_args(field.annotation)) else int
    bounds: dict = {}
    for bound in field.metadata:
        for attribute, side, excluded in (
            ("ge", "low", False),
            ("gt", "low", True),
            ("le", "high", False),
            ("lt", "high", True),
        ):
            value = getattr(bound, attribute, None)
            if value is not None and kind is int:
                bounds[side] = value + (0 if not excluded else 1 if side == "low" else -1)
            elif value is not None:
                bounds[side], bounds[f"open_{side}"] = value, excluded
    return Bounded(kind, **bounds)


#: What a file system's refusal means, for the line that names the file (an error of the machine, not the command).
FILE_SYSTEM = {
    errno.ENOSPC: "no space left on the device",
    errno.EDQUOT: "the disk quota is used up",
    errno.EROFS: "the file system is read-only",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
    errno.EISDIR: "is a folder where a file is needed",
    errno.ENOTDIR: "a part of the path is a file where a folder is needed",
    errno.EEXIST: "is in the way: something of another kind is there already",
    errno.ENAMETOOLONG: "the name is too long",
    errno.EPIPE: "closed by the reader",
}


def file_system_error(error: BaseException) -> str | None:
    """The line for an error of the file system the command met (its file named; a write that names none, the
    standard stream that failed), or None for any other error."""
    if not isinstance(error, OSError) or error.errno not in FILE_SYSTEM:
        return None
    said = error.strerror if error.strerror and error.strerror[0].islower() else FILE_SYSTEM[error.errno]
    if error.filename is not None:
        return f"{error.filename}: {said}"
    for name, stream in (("stdout", sys.stdout), ("stderr", sys.stderr)):
        try:
            stream.flush()
        except OSError:
            nowhere = os.open(os.devnull, os.O_WRONLY)
            os.dup2(nowhere, stream.fileno())  # nothing more to say there, at exit either
            os.close(nowhere)
            return f"{name}: {FILE_SYSTEM[error.errno]}"
    return f"{FILE_SYSTEM[error.errno]} ({error.strerror or error})"


def _one_line(error: BaseException) -> str:
    """An error as one line: an OSError names its file."""
    if isinstance(error, OSError) and error.filename is not None:
        return f"{error.filename}: {error.strerror or error}"
    text = " ".join(str(error).split()) or type(error).__name__
    return text if isinstance(error, InputError) else f"{type(error).__name__}: {text}"


def add_debug_option(parser: argparse.ArgumentParser) -> None:
    """The `--debug` option (read by `run_command`): print the traceback of an unexpected error."""
    parser.add_argument("--debug", action="store_true", help="print the whole traceback of an unexpected error")


def die_with_parent() -> None:
    """In a child between fork and exec (`subprocess.Popen(preexec_fn=...)`): have the kernel end it with SIGTERM
    when the process that started it dies, however it dies (Linux; elsewhere nothing)."""
    if sys.platform.startswith("linux"):
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)


#: Seconds an interrupted command has to stop by itself (its tasks' shutdown, Prefect's last reports) before it is
#: ended: every writer survives a kill (atomic files, locked appends, stores rolled back), so nothing is lost.
STOP_WITHIN_S = 20.0


class _Interrupt:
    """The SIGINT handler while a command runs: the first interrupt raises KeyboardInterrupt (a clean stop) and
    starts a clock that ends the process after `STOP_WITHIN_S` however busy its threads keep it; a second ends it
    at once. `said`: the command has said "interrupted" itself."""

    def __init__(self, prog: str) -> None:
        self.prog, self.interrupted, self.said, self.running = prog, False, False, True
        self._timer: threading.Timer | None = None

    def __call__(self, signum: int, frame: object) -> None:
        if self.interrupted or not self.running:  # a second interrupt, or one after the command while it ends
            self.stop()
        self.interrupted = True
        self._timer = threading.Timer(STOP_WITHIN_S, self.stop)
        self._timer.daemon = True
        self._timer.start()
        raise KeyboardInterrupt

    def stop(self) -> None:
        if not self.said:
            print(f"{self.prog}: interrupted; run it again to resume", file=sys.stderr, flush=True)
        os._exit(130)

    def cancel(self) -> None:
        """No clock running any more (for a caller in this process that goes on after the command)."""
        if self._timer is not None:
            self._timer.cancel()


def _handler(prog: str) -> _Interrupt | None:
    """The command's SIGINT handler, installed where the interrupt is Python's or the loading one's (not in another
    thread, not where SIGINT is ignored or someone else's)."""
    if threading.current_thread() is not threading.main_thread():
        return None
    if signal.getsignal(signal.SIGINT) not in (interrupted_while_loading, signal.default_int_handler):
        return None
    handler = _Interrupt(prog)
    signal.signal(signal.SIGINT, handler)
    return handler


def run_command(main: Callable[[list[str] | None], Any], prog: str, argv: list[str] | None = None) -> Any:
    """Run a command's `main`: an `InputError` (bad input met before or during the work) is one line and exit status
    2, any other error one line and exit status 1 (the traceback with `--debug`), an interrupt "interrupted" and
    130 (within `STOP_WITHIN_S`, or at once on a second interrupt). As a process's entry point (`argv` None), an
    interrupted command keeps its handler while the interpreter ends (waiting on threads, say), so a second
    interrupt still ends it at once, without a traceback; called in-process (`argv` given), Python's handler is
    put back and no clock is left running."""
    debug = "--debug" in (sys.argv[1:] if argv is None else argv)
    handler = _handler(prog)
    try:
        return _run_main(main, prog, argv, debug)
    except SystemExit as stop:
        if handler is not None and stop.code == 130:
            handler.said = True
        raise
    finally:
        if handler is not None:
            handler.running = False
        if handler is not None and (argv is not None or not handler.interrupted):
            handler.cancel()
            signal.signal(signal.SIGINT, signal.default_int_handler)


def _run_main(main: Callable[[list[str] | None], Any], prog: str, argv: list[str] | None, debug: bool) -> Any:
    try:
        try:
            result = main(argv)
        except SystemExit:  # `--help`, a usage error: what they printed is flushed here too
            sys.stdout.flush()
            raise
        sys.stdout.flush()  # a full device or a closed pipe is this command's to name, not the interpreter's at exit
        return result
    except KeyboardInterrupt:
        print(f"{prog}: interrupted; run it again to resume", file=sys.stderr, flush=True)
        raise SystemExit(130) from None
    except Exception as error:
        if debug:
            raise
        machine = file_system_error(error)
        hint = "" if isinstance(error, InputError) or machine else " (run with --debug for the traceback)"
        print(f"{prog}: error: {machine or _one_line(error)}{hint}", file=sys.stderr)
        raise SystemExit(2 if isinstance(error, InputError) else 1) from None


def named_world(argv: list[str]) -> str:
    """The `--world` an argument list names (`--world W` or `--world=W`; default road): which world's command to
    parse it as."""
    world = "road"
    for i, arg in enumerate(argv):
        if arg == "--world" and i + 1 < len(argv):
            world = argv[i + 1]
        elif arg.startswith("--world="):
            world = arg.split("=", 1)[1]
    return world
