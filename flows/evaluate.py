"""`python -m flows.evaluate [--world W]`: a world's techniques played into a run of its results store.

The road's (the default) is the paper's Table 1 protocol over recorded evaluation episodes
(`dynplan.worlds.road.evaluate`): the run `evaluation` is Table 1's, `--table1` plays every case of it, and
`--first-seed 2000000` with its own `--log-dir` and `--run` plays the validation episodes where a world model's
settings are chosen. Every world's evaluation takes the same path (`flows.worlds`): its cases in lockstep batches,
one Prefect task each, resuming per episode; `--world W --help` lists W's options, `--check` checks a run's rows.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from dynplan.cli import run_command
from flows.worlds import evaluate_main, world_command


def main(argv: Sequence[str] | None = None) -> list[dict]:
    argv = sys.argv[1:] if argv is None else list(argv)
    return evaluate_main(*world_command("python -m flows.evaluate", argv, lambda parts: parts.evaluate), argv)


if __name__ == "__main__":
    run_command(main, "python -m flows.evaluate")
