"""The road's halves of the commands every world shares (`dynplan.world_parts`): `flows.replay`'s and
`flows.play`'s (its evaluation's are `evaluate.py`).

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
from dynplan.data.collect import CollectPlan
from dynplan.evaluation.agent import AgentSpec
from dynplan.evaluation.cases import AGENT_SPEEDS, road_models
from dynplan.evaluation.replay import default_outputs, planners, prepare, replay
from dynplan.evaluation.techniques import TECHNIQUES
from dynplan.extras import MissingExtra, require
from dynplan.logs.live import DEFAULT_PORT, LiveView
from dynplan.paths import PathArgument, PathKind, check_output
from dynplan.worlds.road.play import HORIZONS, PlayState, build_state


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
            type=PathArgument(PathKind.OUTPUT_LOG),
            help="replay MCAP to write (default: ../replays/EPISODE.replay-PLANNER.mcap from the log)",
        )
        parser.add_argument(
            "--gif",
            type=PathArgument(PathKind.OUTPUT_GIF),
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


class Play:
    """`python -m flows.play`: steer the agent with the keyboard in the road world or in the world model's
    imagination, or watch the planner play.

    Modes:
      you play       each key press moves the agent one step and the world one frame (the world does not wait
                     otherwise: it is turn-based, as the planner plays)
      imagination    the frames come from the learned world model (--model), rolled forward one at a time from
                     the last four real frames; the agent is judged on them, and the true world is drawn beside
      planner plays  the planner (--technique, oracle or learned) chooses every step; its predicted frame at the
                     horizon k is drawn beside the truth

    Keys:
      W E D C X Z A Q   move up, up-right, right, down-right, down, down-left, left, up-left (arrows: the four axes)
      I                 switch between the real world and the imagination
      K                 the planner's horizon k: 1, 3, 5, 10
      P                 the planner plays / you play
      SPACE             pause or resume the planner
      R                 restart the episode
      ESC               quit (with --record, the log is written first)

    With --live, every step is also served over the Foxglove WebSocket protocol (open it with the replay layout).
    `--world W` plays another world through its own options and panels (`--world W --help`).
    """

    scale = 8
    fps = 8.0

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        source = parser.add_mutually_exclusive_group()
        seed_help = "play the world of this seed (default 2,000,000)"
        source.add_argument("--seed", type=bounded(CollectPlan, "seed"), default=None, help=seed_help)
        log_help = "play the world recorded in this episode log (.mcap)"
        source.add_argument("--log", type=PathArgument(PathKind.LOG), default=None, help=log_help)
        speed_help = "1.0 is the 2x agent, 0.5 the 1x"
        parser.add_argument("--agent-speed", type=float, default=1.0, choices=AGENT_SPEEDS, help=speed_help)
        model_help = "the world model of the imagination and of a learned planner"
        parser.add_argument("--model", default="default", choices=road_models(), help=model_help)
        searching = [n for n, t in TECHNIQUES.items() if t.search]
        technique_help = "the planner that plays when you press P or pass --watch"
        parser.add_argument("--technique", default="oracle", choices=searching, help=technique_help)
        horizon = "the planner's horizon"
        parser.add_argument("-k", "--rollout-steps", type=int, default=3, choices=HORIZONS, help=horizon)
        no_imagination = "do not load a world model for the imagination"
        parser.add_argument("--no-imagination", action="store_true", help=no_imagination)
        live_help = "also serve every step over the Foxglove WebSocket protocol (the live extra)"
        parser.add_argument("--live", action="store_true", help=live_help)
        port_help = "the live view's port (0: any free one)"
        parser.add_argument("--live-port", type=Bounded(int, 0, 65535), default=DEFAULT_PORT, help=port_help)

    def state(self, args: argparse.Namespace) -> PlayState:
        """The episode the options ask for; with --live, its live view serving already."""
        if args.log is not None and args.record is not None:
            check_output(args.record, "--record", "file", inputs=(args.log,))
        imagination, k = not args.no_imagination, args.rollout_steps
        state = build_state(args.seed, args.log, args.agent_speed, args.model, args.technique, k, imagination)
        if args.live:
            try:
                state.live = LiveView(port=args.live_port)
            except (MissingExtra, RuntimeError, OSError) as error:
                raise ValueError(f"--live: {error}") from None
            print(f"serving every step live on {state.live.url} (Foxglove: Open connection, Foxglove WebSocket)")
        return state
