"""`python -m flows.play [--world W]`: steer a world's agent with the keyboard, or watch its planner play.

The road's (the default): you play in the world or in the world model's imagination, or the planner plays, its
prediction drawn beside the truth (`dynplan.worlds.road.commands.Play`: `--help` lists its modes and keys). Every
world's window takes the same path (`flows.worlds.play_window`): `--world W --help` lists W's options and keys.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence

from dynplan.cli import CommandParser, run_command
from dynplan.world_parts import PlayState
from flows.window import NO_DISPLAY, has_display


def main(argv: Sequence[str] | None = None) -> PlayState:
    argv = sys.argv[1:] if argv is None else list(argv)
    headless = any(a == "--script" or a.startswith("--script=") for a in argv)
    if not (has_display() or headless or "-h" in argv or "--help" in argv):
        CommandParser(prog="python -m flows.play").error(NO_DISPLAY)  # before any world loads: at once
    from flows.worlds import play_main, world_command

    return play_main(*world_command("python -m flows.play", argv, lambda parts: parts.play), argv)


if __name__ == "__main__":
    os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
    run_command(main, "python -m flows.play")
