"""`python -m flows.replay log.mcap`: run a planner against a recorded episode.

Prints the outcome (goal / timeout / death), the steps and the time per decision; writes a replay MCAP
(world, the agent's pose, actions and view, the planner's imagined frames) and optionally a GIF.
`--world W` replays another world's log through its own options (`--world W --help`; `flows.worlds`).
"""

from __future__ import annotations

import argparse
import json
import sys
from contextlib import nullcontext
from pathlib import Path

from prefect import flow

from dynplan.cli import Bounded, CommandParser, add_debug_option, bounded
from dynplan.config import ConfigError, field_help
from dynplan.evaluation.agent import AgentSpec
from dynplan.evaluation.cases import AGENT_SPEEDS, road_models
from dynplan.evaluation.replay import default_outputs, planners, prepare, replay
from dynplan.evaluation.techniques import TECHNIQUES
from dynplan.extras import MissingExtra, require
from dynplan.logs.live import DEFAULT_PORT, LiveView
from dynplan.logs.reader import LogError
from dynplan.paths import PathArgument, PathKind, check_output
from dynplan.world import DEFAULT_WORLD, world_names
from flows.cli import run
from flows.worlds import own_command, replay_main


@flow(name="replay-episode", log_prints=True)
def replay_episode(
    log: str,
    agent: AgentSpec | None = None,
    agent_speed: float = 1.0,
    out: str | None = None,
    gif: str | None = None,
    live_port: int | None = None,
    live_wait_s: float = 30.0,
    live_fps: float = 8.0,
) -> dict:
    """Replay one recorded episode through `agent`; with `live_port`, also serve it live to Foxglove."""
    with LiveView(port=live_port) if live_port is not None else nullcontext() as view:
        if view is not None:
            print(
                f"serving the episode live on {view.url} (Foxglove: Open connection, Foxglove WebSocket); "
                f"waiting up to {live_wait_s:g} s for a viewer"
            )
            if not view.wait_for_viewer(live_wait_s):
                print("no viewer connected; replaying anyway")
        result = replay(log, agent, agent_speed, out, gif, view, 0.0 if view is None else 1.0 / live_fps)
    result = result.to_dict()
    print(
        f"{result['outcome']} after {result['steps']} steps; decision {result['decision_ms_median']:.3f} ms "
        f"(median), {result['decision_ms_mean']:.3f} ms (mean); replay log: {result['out']}"
    )
    return result


def _parser() -> argparse.ArgumentParser:
    parser = CommandParser(prog="python -m flows.replay", description=__doc__)
    parser.add_argument(
        "--world",
        choices=world_names(),
        default=DEFAULT_WORLD,
        help="the world (default road; `--world W --help` lists another world's options)",
    )
    parser.add_argument("log", type=PathArgument(PathKind.LOG), help="episode log (.mcap) from flows.collect")
    parser.add_argument(
        "--planner",
        default="oracle",
        choices=planners(),
        help="a technique ("
        + ", ".join(f"{n}: {t.description}" for n, t in TECHNIQUES.items())
        + "), or model: the learned model with --samples and --futures (default oracle)",
    )
    parser.add_argument("--model", default="default", choices=road_models(), help="learned model configuration")
    for name in ("samples", "futures", "rollout_steps", "playouts"):
        parser.add_argument(
            f"--{name.replace('_', '-')}",
            type=bounded(AgentSpec, name),
            default=AgentSpec.model_fields[name].default,
            help=field_help(AgentSpec, name),
        )
    parser.add_argument("--device", default="cpu", help=field_help(AgentSpec, "device"))
    parser.add_argument(
        "--agent-speed", type=float, default=1.0, choices=AGENT_SPEEDS, help="1.0 (the paper's 2×) or 0.5 (1×)"
    )
    parser.add_argument(
        "--out",
        type=PathArgument(PathKind.OUTPUT_FILE),
        help="replay MCAP to write (default: ../replays/EPISODE.replay-PLANNER.mcap from the log)",
    )
    parser.add_argument(
        "--gif",
        type=PathArgument(PathKind.OUTPUT_FILE),
        help="also write a GIF: observed | true future | predicted | error",
    )
    parser.add_argument(
        "--model-dir", type=PathArgument(PathKind.MODEL_FOLDER), help=field_help(AgentSpec, "model_dir")
    )
    parser.add_argument("--seed", type=bounded(AgentSpec, "seed"), default=0, help=field_help(AgentSpec, "seed"))
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    _add_live_options(parser)
    add_debug_option(parser)
    return parser


def _add_live_options(parser: argparse.ArgumentParser) -> None:
    """The live view over the Foxglove WebSocket protocol."""
    parser.add_argument(
        "--live",
        action="store_true",
        help="also serve the episode over the Foxglove WebSocket protocol while it is planned "
        "(the layout dynplan/logs/layouts/replay.json shows it; the live extra)",
    )
    parser.add_argument(
        "--live-port", type=Bounded(int, 0, 65535), default=DEFAULT_PORT, help="the live view's port (0: any free one)"
    )
    parser.add_argument(
        "--live-wait",
        type=Bounded(float, 0.0, 86400.0),
        default=30.0,
        help="seconds to wait for a viewer to subscribe before it starts (default 30)",
    )
    parser.add_argument(
        "--live-fps",
        type=Bounded(float, 0.01, 1000.0),
        default=8.0,
        help="decisions shown per second at most (default 8)",
    )


def _agent(args: argparse.Namespace) -> AgentSpec:
    """The agent the command line describes (a ConfigError naming a bad value)."""
    return AgentSpec(
        technique=args.planner,
        model=args.model,
        model_dir=args.model_dir,
        samples=args.samples,
        futures=args.futures,
        playouts=args.playouts,
        rollout_steps=args.rollout_steps,
        device=args.device,
        seed=args.seed,
    )


def main(argv: list[str] | None = None) -> dict:
    argv = sys.argv[1:] if argv is None else argv
    if (own := own_command(argv, lambda parts: parts.replay)) is not None:
        return replay_main(*own, argv)
    parser = _parser()
    args = parser.parse_args(argv)
    if args.world != DEFAULT_WORLD:  # an abbreviated --world reaches here: spell it out to dispatch
        parser.error(f"--world {args.world}: give it as --world {args.world} (in full) for its own options")
    try:  # fail fast, with one line, before any flow machinery starts
        agent = _agent(args)
        out = args.out or str(default_outputs(args.log, agent))
        if args.live:
            require("foxglove", "live", "--live")
        check_output(out, "--out", "file", inputs=(args.log,))
        if args.gif:
            if Path(args.gif).resolve() == Path(out).resolve():
                raise ValueError(f"--gif {args.gif}: is the path of --out too; give the GIF a path of its own")
            check_output(args.gif, "--gif", "file", inputs=(args.log,))
        prepare(args.log, agent, args.agent_speed)
    except (LogError, ConfigError, ValueError, MissingExtra) as error:
        parser.error(str(error))
    result = replay_episode(
        args.log,
        agent,
        args.agent_speed,
        out,
        args.gif,
        args.live_port if args.live else None,
        args.live_wait,
        args.live_fps,
    )
    if args.json:
        print(json.dumps(result))
    return result


if __name__ == "__main__":
    run(main, "python -m flows.replay")
