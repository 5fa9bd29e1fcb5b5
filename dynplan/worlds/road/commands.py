"""The road's halves of the commands every world shares (`dynplan.world_parts`): `flows.replay`'s.

The road is the default world, so these are the commands without `--world`; they run the road's agents
(`dynplan.evaluation`) against its recorded episodes.
"""

from __future__ import annotations

import argparse
from contextlib import nullcontext
from pathlib import Path

from pydantic import Field

from dynplan.cli import Bounded, bounded
from dynplan.config import Config, field_help
from dynplan.evaluation.agent import AgentSpec
from dynplan.evaluation.cases import AGENT_SPEEDS, road_models
from dynplan.evaluation.replay import default_outputs, planners, prepare, replay
from dynplan.evaluation.techniques import TECHNIQUES
from dynplan.extras import require
from dynplan.logs.live import DEFAULT_PORT, LiveView
from dynplan.paths import PathArgument, PathKind, check_output


class RoadReplay(Config):
    """One replay: the recorded episode `log`, the agent and its speed, the replay log `out` (and a GIF), and the
    live view's port (None: none), how long it waits for a viewer and how many decisions it shows a second."""

    log: str
    agent: AgentSpec
    agent_speed: float = 1.0
    out: str
    gif: str | None = None
    live_port: int | None = Field(None, ge=0, le=65535)
    live_wait: float = Field(30.0, ge=0.0, le=86400.0)
    live_fps: float = Field(8.0, ge=0.01, le=1000.0)


class Replay:
    """`python -m flows.replay LOG.mcap`: run a planner against a recorded episode.

    Prints the outcome (goal / timeout / death), the steps and the time per decision; writes a replay MCAP (world,
    the agent's pose, actions and view, the planner's imagined frames) and optionally a GIF. `--world W` replays
    another world's log through its own options (`--world W --help`).
    """

    request_type = RoadReplay

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        techniques = ", ".join(f"{n}: {t.description}" for n, t in TECHNIQUES.items())
        parser.add_argument(
            "--planner",
            default="oracle",
            choices=planners(),
            help=f"a technique ({techniques}), or model: the learned model with --samples and --futures "
            "(default oracle)",
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
        _add_live_options(parser)

    def request(self, args: argparse.Namespace) -> RoadReplay:
        """The replay the arguments ask for, every input checked before any flow machinery starts."""
        agent = AgentSpec(
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
        out = args.out or str(default_outputs(args.log, agent))
        if args.live:
            require("foxglove", "live", "--live")
        check_output(out, "--out", "file", inputs=(args.log,))
        if args.gif:
            if Path(args.gif).resolve() == Path(out).resolve():
                raise ValueError(f"--gif {args.gif}: is the path of --out too; give the GIF a path of its own")
            check_output(args.gif, "--gif", "file", inputs=(args.log,))
        prepare(args.log, agent, args.agent_speed)
        live = {"live_port": args.live_port if args.live else None, "live_wait": args.live_wait}
        return RoadReplay(
            log=args.log,
            agent=agent,
            agent_speed=args.agent_speed,
            out=out,
            gif=args.gif,
            **live,
            live_fps=args.live_fps,
        )

    def replay(self, request: RoadReplay) -> dict:
        """Replay the episode through the agent; with a live port, also serve it live to Foxglove."""
        port = request.live_port
        with LiveView(port=port) if port is not None else nullcontext() as view:
            if view is not None:
                print(
                    f"serving the episode live on {view.url} (Foxglove: Open connection, Foxglove WebSocket); "
                    f"waiting up to {request.live_wait:g} s for a viewer"
                )
                if not view.wait_for_viewer(request.live_wait):
                    print("no viewer connected; replaying anyway")
            pace = 0.0 if view is None else 1.0 / request.live_fps
            result = replay(request.log, request.agent, request.agent_speed, request.out, request.gif, view, pace)
        return result.to_dict()

    def describe(self, result: dict) -> str:
        return (
            f"{result['outcome']} after {result['steps']} steps; decision {result['decision_ms_median']:.3f} ms "
            f"(median), {result['decision_ms_mean']:.3f} ms (mean); replay log: {result['out']}"
        )


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
