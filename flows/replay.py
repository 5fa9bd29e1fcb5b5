"""`python -m flows.replay [--world W] LOG.mcap`: run a world's planner against a recorded episode.

The road's (the default): prints the outcome (goal / timeout / death), the steps and the time per decision; writes
a replay MCAP (world, the agent's pose, actions and view, the planner's imagined frames) and optionally a GIF.
Every world's replay takes the same path (`flows.worlds`): `--world W --help` lists W's options.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from dynplan.cli import run_command
from flows.worlds import replay_main, world_command


def main(argv: Sequence[str] | None = None) -> dict:
    argv = sys.argv[1:] if argv is None else list(argv)
    return replay_main(*world_command("python -m flows.replay", argv, lambda parts: parts.replay), argv)


if __name__ == "__main__":
    run_command(main, "python -m flows.replay")
