"""The kinds of path a command or the API takes, each checked before any work: an output file or folder, an input log,
a log folder, a frames store, a results folder, a weights file, a model folder.

Each check refuses what is not of its kind — an empty string, a link loop, a device node or a folder where a file is
meant, a file where a folder is, a missing or unreadable input, an output that is an input or inside one, or inside
the installed package — with a `PathError` naming the parameter, the path and what was wrong, and returns the path
resolved. `PathArgument` is the same check as an argparse `type`, so every command declares each path option's kind
where it declares the option.
"""

from __future__ import annotations

import argparse
import enum
import os
import stat
from dataclasses import dataclass
from pathlib import Path

from dynplan.cli import InputError


class PathError(InputError, argparse.ArgumentTypeError):
    """A path cannot be used as what it is given for; the message names the parameter, the path and why."""


class PathKind(enum.Enum):
    """What a path is given for: (is it read or written, a file or a folder, the suffix a file must have)."""

    OUTPUT_FILE = ("output", "file", "", "output file")  # the last field keeps each kind its own member
    OUTPUT_LOG = ("output", "file", ".mcap", "output log")
    OUTPUT_GIF = ("output", "file", ".gif", "GIF")
    OUTPUT_PNG = ("output", "file", ".png", "PNG")
    OUTPUT_FOLDER = ("output", "folder", "", "output folder")
    LOG = ("input", "file", ".mcap", "log")
    LOG_FOLDER = ("input", "folder", "", "log folder")
    STORE = ("input", "folder", "", "store")
    RESULTS_FOLDER = ("input", "folder", "", "results folder")
    WEIGHTS = ("input", "file", ".pt", "weights")
    MODEL_FOLDER = ("input", "folder", "", "model folder")

    @property
    def role(self) -> str:
        return self.value[0]

    @property
    def shape(self) -> str:
        return self.value[1]

    @property
    def suffix(self) -> str:
        return self.value[2]

    @property
    def missing(self) -> str:
        """What a missing input of this kind is called, and how one is made."""
        return _MISSING.get(self.name, f"no such {self.shape}")


_MISSING = {
    "LOG": "no such episode log",
    "LOG_FOLDER": "no such folder of episode logs (record some with python -m flows.collect --out FOLDER)",
    "STORE": "no such store (build it with python -m flows.build_datasets LOG_DIR --out STORE)",
    "RESULTS_FOLDER": "no such folder (it is read, never created)",
    "WEIGHTS": "no such checkpoint",
}


def _what(mode: int) -> str:
    """What a non-regular file is, in words."""
    kinds = (
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISFIFO, "a named pipe"),
        (stat.S_ISSOCK, "a socket"),
        (stat.S_ISDIR, "a folder"),
        (stat.S_ISREG, "a file"),
    )
    for test, name in kinds:
        if test(mode):
            return name
    return "not a regular file"


def _resolve(value: str | os.PathLike, parameter: str) -> Path:
    """`value` expanded and resolved; an empty or unresolvable path is a PathError."""
    try:
        text = os.fspath(value)
    except TypeError:
        raise PathError(f"{parameter} {value!r}: is not a path") from None
    if not isinstance(text, str) or not text.strip():
        raise PathError(f"{parameter} {text!r}: is empty; give a path")
    if "\0" in text:
        raise PathError(f"{parameter} {text!r}: holds a NUL character")
    try:
        return Path(text).expanduser().resolve()
    except RuntimeError:  # Python 3.11 reports a symbolic link loop so
        raise PathError(f"{parameter} {text}: is a symbolic link loop") from None
    except OSError as error:
        raise PathError(f"{parameter} {text}: {error.strerror or error}") from None


def _stat(path: Path, parameter: str, shown: str) -> os.stat_result | None:
    """`path`'s status, None if it does not exist; an unreadable status (a loop, a name too long) is a PathError."""
    try:
        return path.stat()
    except FileNotFoundError:
        return None
    except NotADirectoryError:
        return None
    except OSError as error:
        raise PathError(f"{parameter} {shown}: {error.strerror or error}") from None


def check_input(value: str | os.PathLike, parameter: str, kind: PathKind) -> Path:
    """Check that `value` is an existing, readable file or folder as `kind` says (a file with `kind`'s suffix)."""
    path, shown = _resolve(value, parameter), os.fspath(value)
    status = _stat(path, parameter, shown)
    if status is None:
        raise PathError(f"{parameter} {shown}: {kind.missing}")
    if kind.shape == "folder" and not stat.S_ISDIR(status.st_mode):
        raise PathError(f"{parameter} {shown}: is {_what(status.st_mode)}, not a folder; give the path of a folder")
    if kind.shape == "file" and not stat.S_ISREG(status.st_mode):
        raise PathError(f"{parameter} {shown}: is {_what(status.st_mode)}, not a regular file; give the path of a file")
    if kind.suffix and Path(shown).suffix != kind.suffix:  # as given: a link may point at a blob without one
        raise PathError(f"{parameter} {shown}: is not a {kind.suffix} file")
    wanted = os.R_OK | (os.X_OK if kind.shape == "folder" else 0)
    if not os.access(path, wanted):
        raise PathError(f"{parameter} {shown}: is not readable")
    return path


def _inside(path: Path, folder: Path) -> bool:
    return folder in path.parents


#: The installed package: its modules and committed weights are no command's output.
PACKAGE = Path(__file__).resolve().parent


def _not_an_input(out: Path, shown: str, parameter: str, shape: str, inputs: tuple) -> None:
    if out == PACKAGE or _inside(out, PACKAGE):
        raise PathError(f"{parameter} {shown}: is inside the installed package {PACKAGE}; choose a path outside it")
    for source in inputs:
        source = _resolve(source, "input")
        if out == source:
            raise PathError(f"{parameter} {shown}: is an input of this command; choose another path")
        if not source.is_file() and _inside(out, source):  # a folder, or one still to be made
            raise PathError(f"{parameter} {shown}: is inside {source}, which this command reads; choose another path")
        if shape == "folder" and _inside(source, out):
            raise PathError(f"{parameter} {shown}: holds {source}, which this command reads; choose another path")


def check_output(
    path: str | os.PathLike, parameter: str, kind: str = "file", inputs: tuple[str | os.PathLike, ...] = ()
) -> Path:
    """Check, before any work, that `path` can be written as a `kind` ("file" or "folder"): it is not inside the
    installed package, not one of `inputs`, not inside an input folder nor holding an input (a folder); an existing
    file is a regular one (never a device node, a pipe or a socket), an existing folder a folder; and the folder it
    goes in is writable. Returns it resolved; otherwise a PathError naming `parameter`, the path and why."""
    out, shown = _resolve(path, parameter), os.fspath(path)
    _not_an_input(out, shown, parameter, kind, inputs)
    status = _stat(out, parameter, shown)
    if status is not None and kind == "file" and not stat.S_ISREG(status.st_mode):
        fix = "give the path of a file" if stat.S_ISDIR(status.st_mode) else "only regular files are written"
        raise PathError(f"{parameter} {shown}: is {_what(status.st_mode)}; {fix}")
    if status is not None and kind == "folder" and not stat.S_ISDIR(status.st_mode):
        what = "a file" if stat.S_ISREG(status.st_mode) else _what(status.st_mode)
        raise PathError(f"{parameter} {shown}: is {what}; give the path of a folder")
    start = out if kind == "folder" and status is not None else out.parent
    folder = next(candidate for candidate in (start, *start.parents) if candidate.exists())
    if not folder.is_dir():
        raise PathError(f"{parameter} {shown}: {folder} is a file, so nothing can be written under it")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise PathError(f"{parameter} {shown}: {folder} is not writable")
    return out


def check_path(value: str | os.PathLike, parameter: str, kind: PathKind, inputs: tuple = ()) -> Path:
    """Check `value` as `kind` (see `check_input` and `check_output`; an output of a kind with a suffix is named with
    it, so that a file is what its name says); returns it resolved."""
    if kind.role == "output":
        out, shown = check_output(value, parameter, kind.shape, inputs), os.fspath(value)
        if kind.suffix and Path(shown).suffix.lower() != kind.suffix:
            raise PathError(
                f"{parameter} {shown}: is not a {kind.suffix} name; what is written there is a {kind.suffix} file"
            )
        return out
    return check_input(value, parameter, kind)


@dataclass(frozen=True)
class PathArgument:
    """An argparse `type` for a path option of `kind`: the option's value checked as `check_path` does, returned as
    given. Relations between options (an output that is an input) are checked by the command after parsing."""

    kind: PathKind

    def __call__(self, value: str) -> str:
        check_path(value, "", self.kind)
        return value

    @property
    def __name__(self) -> str:  # argparse names a type by it
        return self.kind.name.lower()
