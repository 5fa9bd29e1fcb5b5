"""The play windows' common parts, whichever world they play: a window of titled panels side by side with lines of
text below (`PanelWindow`), and what a play command checks before it opens one — its output files, pygame, and the
key names of a headless script, each refused in one line by the command's parser."""

from __future__ import annotations

import argparse
import os
import sys
import warnings
from collections.abc import Sequence

import numpy as np

from dynplan.cli import Bounded
from dynplan.paths import PathArgument, PathKind, check_output
from dynplan.render import upscale

#: The environment variables that name a display on Linux: X11's and Wayland's, and SDL's own choice of driver.
DISPLAY_VARIABLES = ("DISPLAY", "WAYLAND_DISPLAY", "SDL_VIDEODRIVER")
INSTALL = "the play window needs pygame: pip install 'dynplan[play]' (or pip install pygame-ce)"
#: Pixels between panels.
GAP = 8


class PanelWindow:
    """A pygame window of `panels` images of `shape` (H, W) side by side, each enlarged `scale` times under its
    title, and `text_height` pixels of text below."""

    def __init__(self, shape: tuple[int, int], panels: int, scale: int, caption: str, text_height: int) -> None:
        import pygame

        self.pygame, self.scale = pygame, scale
        pygame.display.init()
        pygame.font.init()
        self.panel = (shape[1] * scale, shape[0] * scale)
        self.screen = pygame.display.set_mode(
            (panels * self.panel[0] + (panels + 1) * GAP, self.panel[1] + text_height)
        )
        pygame.display.set_caption(caption)
        self.font = pygame.font.Font(None, 22)

    def blit(self, image: np.ndarray, column: int, title: str) -> None:
        """An RGB image (H, W, 3) into panel `column`, under `title`."""
        surface = self.pygame.surfarray.make_surface(upscale(image, self.scale).transpose(1, 0, 2))
        x = GAP + column * (self.panel[0] + GAP)
        self.screen.blit(surface, (x, 28))
        self.screen.blit(self.font.render(title, True, (230, 230, 230)), (x, 6))

    def text(self, lines: Sequence[str]) -> None:
        """Lines of text below the panels."""
        for i, line in enumerate(lines):
            self.screen.blit(self.font.render(line, True, (230, 230, 230)), (GAP, self.panel[1] + 40 + 24 * i))

    def show(self, panels: Sequence[tuple[np.ndarray, str]], lines: Sequence[str]) -> None:
        """A whole picture: each (RGB image, title) in its panel, the lines below, on the screen."""
        self.screen.fill((20, 20, 24))
        for column, (image, title) in enumerate(panels):
            self.blit(image, column, title)
        self.text(lines)
        self.pygame.display.flip()


def add_window_options(parser: argparse.ArgumentParser, scale: int, fps: float, pixel: str) -> None:
    """The play window's options: its scale (default `scale` screen pixels per `pixel`), the planner's frame rate
    (default `fps`), a last picture and a headless script of keys."""
    parser.add_argument(
        "--scale", type=int, default=scale, choices=range(1, 17), metavar="1..16", help=f"pixels per {pixel}"
    )
    parser.add_argument(
        "--fps", type=Bounded(float, 0.01, 1000.0), default=fps, help="frames per second while the planner plays"
    )
    parser.add_argument(
        "--screenshot",
        type=PathArgument(PathKind.OUTPUT_PNG),
        default=None,
        help="save the window's last picture to this PNG at the end",
    )
    parser.add_argument(
        "--script", default=None, help="key names separated by commas, one per frame, then quit (headless runs)"
    )


def checked_window_options(
    parser: argparse.ArgumentParser, args: argparse.Namespace, inputs: Sequence[str] = ()
) -> list[str] | None:
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
    if script is not None and len(script) > MAX_SCRIPT:
        parser.error(f"--script: {len(script)} keys; at most {MAX_SCRIPT} (one a frame: longer than any game)")
    _check_display(parser, script)
    for key in script or ():
        try:
            with warnings.catch_warnings():  # the names are pygame's own before its display is initialised
                warnings.simplefilter("ignore")
                pygame.key.key_code(key)
        except ValueError:
            parser.error(f"--script: {key!r} is not a key name (e.g. up, left, space, p, escape)")
    return script


#: The most keys a `--script` holds: one a frame, more than any registered world's episode lasts (at most 2,048).
MAX_SCRIPT = 10_000
NO_DISPLAY = (
    "no display to open the window on (DISPLAY and WAYLAND_DISPLAY are unset): run it on a desktop, or headless "
    "with --script KEYS (e.g. --script p,space,escape) and --screenshot or --record to keep what it played"
)


def has_display() -> bool:
    """Whether a window can open: not Linux, or one of `DISPLAY_VARIABLES` set."""
    return not sys.platform.startswith("linux") or any(os.environ.get(name) for name in DISPLAY_VARIABLES)


def _check_display(parser: argparse.ArgumentParser, script: list[str] | None) -> None:
    """On Linux without a display, a headless script plays on SDL's dummy video driver; without a script the window
    has nowhere to open, which is one line (`NO_DISPLAY`), not a wait."""
    if has_display():
        return
    if script is not None:
        os.environ["SDL_VIDEODRIVER"] = "dummy"
        return
    parser.error(NO_DISPLAY)
