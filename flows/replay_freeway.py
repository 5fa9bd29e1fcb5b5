"""`python -m flows.replay --world freeway LOG.mcap --noop-start N`: play a Freeway episode and write its replay.

LOG is a mode's recording (`flows.collect --world freeway`); the technique (`oracle` by default: the true future)
plays the real game from NOOP start N; the replay log (default `../replays/<log>.replay-<technique>-noop<N>.mcap`
from the log) holds the lanes, the chicken's track and the lanes the planner searched at each decision, for
`python -m flows.view`.
"""

from __future__ import annotations

import argparse
import json

from prefect import flow

from dynplan.cli import CommandParser, add_debug_option, bounded
from dynplan.config import field_help
from dynplan.env.freeway import FreewayEpisode
from dynplan.evaluation.freeway import PLANNERS, TECHNIQUES, world_model_for
from dynplan.evaluation.freeway_replay import GIF_STEPS, default_replay_path, replay_freeway, replayable
from dynplan.logs.reader import LogError
from dynplan.models.checkpoint import CheckpointError
from dynplan.paths import PathArgument, PathKind, check_output
from dynplan.planning.chicken import ChickenSearch


@flow(name="replay-freeway-episode", log_prints=True)
def replay_freeway_episode(log: str, technique: str, noop_start: int, horizon: int, out: str,
                           model_dir: str | None = None, gif: str | None = None) -> dict:  # fmt: skip
    """Replay one Freeway episode of `log`'s mode into `out` (`model_dir`: a learned technique's world model; `gif`:
    where to write the GIF of its first steps)."""
    model = world_model_for(technique, model_dir)
    result = replay_freeway(log, technique, noop_start, ChickenSearch(horizon=horizon), out, model, gif).to_dict()
    ms = "" if result["decision_ms"] is None else f", {result['decision_ms']:g} ms a decision (median)"
    print(f"score {result['score']:g}, {result['knocks']} knocks in {result['steps']} steps{ms}; replay log: {out}")
    return result


def parser() -> argparse.ArgumentParser:
    parser = CommandParser(prog="python -m flows.replay --world freeway", description=__doc__,
                           formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    parser.add_argument("log", type=PathArgument(PathKind.LOG), help="a Freeway mode's log (.mcap) from flows.collect")
    parser.add_argument("--world", choices=["freeway"], default="freeway", help="freeway")
    parser.add_argument("--noop-start", type=bounded(FreewayEpisode, "noop_start"), default=0,
                        help=field_help(FreewayEpisode, "noop_start"))  # fmt: skip
    parser.add_argument("--technique", choices=TECHNIQUES, default="oracle", help="who plays (default oracle)")
    parser.add_argument("--horizon", type=bounded(ChickenSearch, "horizon"), default=8,
                        help=field_help(ChickenSearch, "horizon"))  # fmt: skip
    parser.add_argument("--out", type=PathArgument(PathKind.OUTPUT_FILE), help="the replay log to write")
    parser.add_argument("--model-dir", type=PathArgument(PathKind.MODEL_FOLDER),
                        help="the learned technique's world model: a folder holding vqvae.pt and pixelcnn.pt "
                        "(default: the committed Freeway weights)")  # fmt: skip
    parser.add_argument("--gif", type=PathArgument(PathKind.OUTPUT_FILE),
                        help=f"also write a GIF of the first {GIF_STEPS} steps: the lanes now, the true and the "
                        "searched lanes k steps on, their error (planning techniques)")  # fmt: skip
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    add_debug_option(parser)
    return parser


def main(argv: list[str] | None = None) -> dict:
    commands = parser()
    args = commands.parse_args(argv)
    out = args.out or str(default_replay_path(args.log, args.technique, args.noop_start))
    try:
        check_output(out, "--out", "file", inputs=(args.log,))
        replayable(args.log)
        world_model_for(args.technique, args.model_dir)
        if args.gif:
            if args.technique not in PLANNERS:
                raise ValueError(f"--gif shows the lanes a planner searched; {args.technique} does not plan")
            check_output(args.gif, "--gif", "file", inputs=(args.log, out))
    except (LogError, ValueError, CheckpointError) as error:
        commands.error(str(error))
    result = replay_freeway_episode(args.log, args.technique, args.noop_start, args.horizon, out, args.model_dir,
                                    args.gif)  # fmt: skip
    if args.json:
        print(json.dumps(result))
    return result
