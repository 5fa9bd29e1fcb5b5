"""What a play window checks before it opens, whichever world it plays: its output files, pygame, and the key names
of a headless script — each refused in one line by the command's parser."""

from __future__ import annotations

import argparse
import warnings
from collections.abc import Sequence

from dynplan.paths import check_output

INSTALL = "the play window needs pygame: pip install 'dynplan[play]' (or pip install pygame)"


def checked_window_options(parser: argparse.ArgumentParser, args: argparse.Namespace,
                           inputs: Sequence[str] = ()) -> list[str] | None:  # fmt: skip
    """The key names of `args.script` (None without one), once `--record` and `--screenshot` are files that can be
    written (none of `inputs`), pygame is installed and every key is one of pygame's names."""
    for option, path in (("--record", args.record), ("--screenshot", args.screenshot)):
        if path is not None:
            try:
                check_output(path, option, "file", inputs=inputs)
            except ValueError as error:
                parser.error(str(error))
    try:
        import pygame
    except ImportError:
        parser.exit(2, f"python -m flows.play: error: {INSTALL}\n")
    script = None if args.script is None else [key.strip() for key in args.script.split(",") if key.strip()]
    for key in script or ():
        try:
            with warnings.catch_warnings():  # the names are pygame's own before its display is initialised
                warnings.simplefilter("ignore")
                pygame.key.key_code(key)
        except ValueError:
            parser.error(f"--script: {key!r} is not a key name (e.g. up, left, space, p, escape)")
    return script
