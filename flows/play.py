"""`python -m flows.play`: steer the agent with the keyboard in the road world or in the world model's imagination,
or watch the planner play.

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
`--world W` plays another world through its own options and panels (`--world W --help`; `flows.worlds`).
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Iterable, Sequence

import numpy as np

from dynplan.cli import Bounded, CommandParser, bounded, run_command
from dynplan.data.collect import CollectPlan
from dynplan.env.agent import ACTION_ANGLES_DEG
from dynplan.env.colors import colorize
from dynplan.env.config import RoadConfig
from dynplan.env.road import generate_world
from dynplan.evaluation.agent import AgentSpec
from dynplan.evaluation.cases import AGENT_SPEEDS, VALIDATION_SEED_START, road_models
from dynplan.evaluation.protocol import world_agent
from dynplan.evaluation.techniques import TECHNIQUES
from dynplan.extras import MissingExtra
from dynplan.files import atomic_path
from dynplan.logs.live import DEFAULT_PORT, LiveView
from dynplan.logs.reader import LogError
from dynplan.logs.recording import read_recorded_log
from dynplan.models.checkpoint import CheckpointError
from dynplan.paths import PathArgument, PathKind
from dynplan.play import HORIZONS, PlayState
from dynplan.render import error_image
from dynplan.world import DEFAULT_WORLD, world_names
from dynplan.world_parts import PlayState as WorldPlayState
from flows.window import PanelWindow, add_window_options, checked_window_options
from flows.worlds import own_command, play_main, window_key

#: Key name → heading in degrees (90° is up on screen: row 0 of the world is drawn at the bottom).
MOVE_KEYS = {
    "w": 90,
    "e": 45,
    "d": 0,
    "c": -45,
    "x": -90,
    "z": -135,
    "a": 180,
    "q": 135,
    "up": 90,
    "right": 0,
    "down": -90,
    "left": 180,
}


def action_of(heading: int) -> int:
    """The action index of a heading in degrees (180 is −180)."""
    angle = -180 if heading == 180 else heading
    return int(np.flatnonzero(angle == ACTION_ANGLES_DEG)[0])


def build_state(
    seed: int | None = None,
    log: str | None = None,
    agent_speed: float = 1.0,
    model: str = "default",
    technique_name: str = "oracle",
    k: int = 3,
    imagination: bool = True,
) -> PlayState:
    """The state of the world of `seed` or of the recorded `log`: the imagination from the learned world model
    `model` (its mid-point frames, no caution: the frames as the model predicts them), the planner of
    `technique_name` at horizon k."""
    if log is not None:
        world = read_recorded_log(log).world()
    else:
        world = generate_world(RoadConfig(agent_speed=agent_speed), VALIDATION_SEED_START if seed is None else seed)
    imagined = None
    if imagination:
        from dynplan.models.world_model import load_world_model

        imagined = load_world_model(model=model, caution={"occupancy": 0.0, "margin": 0})
    planner, forward = world_agent(
        world, AgentSpec(technique=technique_name, model=model, rollout_steps=k), agent_speed
    )
    return PlayState(world, agent_speed, imagined, planner, forward, k)


class Window(PanelWindow):
    """The pygame window: what you play in, the true world, and the divergence or the planner's prediction."""

    def __init__(self, state: PlayState, scale: int = 8):
        super().__init__(state.world.frames.shape[1:], 3, scale, "dynplan play", 150)
        self.state = state

    def draw(self, planner_plays: bool, paused: bool) -> None:
        s = self.state
        self.screen.fill((20, 20, 24))
        self.blit(colorize(s.frame, s.position), 0, f"playing in the {s.place}")
        self.blit(colorize(s.true_frame, s.position), 1, "the true world")
        if s.place == "imagination":
            self.blit(error_image(s.true_frame, s.frame), 2, "imagined vs true (red: missed, blue: extra)")
        elif s.last_prediction is not None and planner_plays:
            ahead = s.last_prediction.frames
            self.blit(
                error_image(s.world.frames[min(s.t + len(ahead) - 1, len(s.world.frames) - 1)], ahead[-1]),
                2,
                f"predicted t + {len(ahead)} vs true",
            )
        who = ("planner plays" + (" (paused)" if paused else "")) if planner_plays else "you play"
        lines = [
            f"t = {s.t}   {who}   k = {s.k}   outcome: {s.outcome}",
            "move: W E D C X Z A Q or arrows   I: imagination   K: horizon   P: planner/you   SPACE: pause",
            "R: restart   ESC: quit",
        ]
        self.text(lines)
        self.pygame.display.flip()


def publish(live: LiveView, state: PlayState) -> None:
    """Show the state's latest step on the live view: the frame it was judged on, the agent, the step, and the
    planner's search and prediction when it chose the step."""
    track, t = state.track, state.t
    step = track.step_row(-1) if len(track.action) else None
    decision = state.search[-1] if state.search and state.search[-1]["t"] == t - 1 else None
    imagined = None if decision is None or state.last_prediction is None else state.last_prediction.frames
    live.show(t, state.frame, state.world.goal[t], state.position, decision, imagined, step)


def _on_key(state: PlayState, name: str, modes: tuple[bool, bool], live: LiveView | None) -> tuple[bool, bool]:
    """One key press: its effect on the state; `modes` and the result are (planner_plays, paused)."""
    planner_plays, paused = modes
    if (changed := window_key(state, name, planner_plays, paused)) is not None:
        return changed
    if name == "i" and state.imagination is not None:
        state.toggle_imagination()
    elif name in MOVE_KEYS and state.running and not planner_plays:
        state.step(action_of(MOVE_KEYS[name]))
        if live is not None:
            publish(live, state)
    return planner_plays, paused


def play(
    state: PlayState,
    scale: int = 8,
    fps: float = 8.0,
    planner_plays: bool = False,
    script: Iterable[str] | None = None,
    record: str | None = None,
    live: LiveView | None = None,
    screenshot: str | None = None,
) -> PlayState:
    """Run the window until ESC or the window closes. `script`: key names fed in as real key events, one per frame
    (then the window quits) — how the tests play it headless. `live`: also publish every step there;
    `screenshot`: save the window's last picture there (PNG)."""
    import pygame

    window = Window(state, scale)
    clock, paused, keys = pygame.time.Clock(), False, None if script is None else list(script)
    try:
        while True:
            if keys is not None:
                if not keys:
                    break
                pygame.event.post(pygame.event.Event(pygame.KEYDOWN, key=pygame.key.key_code(keys.pop(0))))
            events = pygame.event.get()
            names = [pygame.key.name(e.key) for e in events if e.type == pygame.KEYDOWN]
            for name in names:
                planner_plays, paused = _on_key(state, name, (planner_plays, paused), live)
            if any(e.type == pygame.QUIT for e in events) or "escape" in names:
                break
            if planner_plays and not paused and state.running:
                state.step(state.planner_action())
                if live is not None:
                    publish(live, state)
            window.draw(planner_plays, paused)
            clock.tick(fps)
        if screenshot is not None:
            with atomic_path(screenshot, keep_suffix=True) as tmp:
                pygame.image.save(window.screen, str(tmp))
    finally:
        pygame.quit()
        if record is not None:
            print(f"recorded {state.record(record)}")
    return state


def _parser() -> CommandParser:
    parser = CommandParser(
        prog="python -m flows.play", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--world",
        choices=world_names(),
        default=DEFAULT_WORLD,
        help="the world (default road; `--world W --help` lists another world's options)",
    )
    source = parser.add_mutually_exclusive_group()
    source.add_argument(
        "--seed",
        type=bounded(CollectPlan, "seed"),
        default=None,
        help="play the world of this seed (default 2,000,000)",
    )
    source.add_argument(
        "--log",
        type=PathArgument(PathKind.LOG),
        default=None,
        help="play the world recorded in this episode log (.mcap)",
    )
    parser.add_argument(
        "--agent-speed", type=float, default=1.0, choices=AGENT_SPEEDS, help="1.0 is the 2x agent, 0.5 the 1x"
    )
    parser.add_argument(
        "--model",
        default="default",
        choices=road_models(),
        help="the world model of the imagination and of a learned planner",
    )
    parser.add_argument(
        "--technique",
        default="oracle",
        choices=[n for n, t in TECHNIQUES.items() if t.search],
        help="the planner that plays when you press P or pass --watch",
    )
    parser.add_argument("--watch", action="store_true", help="start with the planner playing")
    parser.add_argument("-k", "--rollout-steps", type=int, default=3, choices=HORIZONS, help="the planner's horizon")
    parser.add_argument("--no-imagination", action="store_true", help="do not load a world model for the imagination")
    parser.add_argument(
        "--record",
        type=PathArgument(PathKind.OUTPUT_FILE),
        default=None,
        help="write what was played to this replay log (.mcap) at the end",
    )
    _add_window_options(parser)
    return parser


def _add_window_options(parser: argparse.ArgumentParser) -> None:
    """The window, the live view and the headless script."""
    add_window_options(parser, 8, 8.0, "cell")
    parser.add_argument(
        "--live",
        action="store_true",
        help="also serve every step over the Foxglove WebSocket protocol (the live extra)",
    )
    parser.add_argument(
        "--live-port", type=Bounded(int, 0, 65535), default=DEFAULT_PORT, help="the live view's port (0: any free one)"
    )


def main(argv: Sequence[str] | None = None) -> PlayState | WorldPlayState:
    argv = sys.argv[1:] if argv is None else list(argv)
    if (own := own_command(argv, lambda parts: parts.play)) is not None:
        return play_main(*own, argv)
    parser = _parser()
    args = parser.parse_args(argv)
    if args.world != DEFAULT_WORLD:  # an abbreviated --world reaches here: spell it out to dispatch
        parser.error(f"--world {args.world}: give it as --world {args.world} (in full) for its own options")
    inputs = () if args.log is None else (args.log,)
    script = checked_window_options(parser, args, inputs)
    try:
        state = build_state(
            args.seed,
            args.log,
            args.agent_speed,
            args.model,
            args.technique,
            args.rollout_steps,
            not args.no_imagination,
        )
    except (LogError, CheckpointError, ValueError) as error:
        parser.exit(2, f"python -m flows.play: error: {error}\n")
    if not args.live:
        return play(state, args.scale, args.fps, args.watch, script, args.record, screenshot=args.screenshot)
    try:
        view = LiveView(port=args.live_port)
    except (MissingExtra, RuntimeError, OSError) as error:
        parser.exit(2, f"python -m flows.play: error: --live: {error}\n")
    with view:
        print(f"serving every step live on {view.url} (Foxglove: Open connection, Foxglove WebSocket)", flush=True)
        return play(state, args.scale, args.fps, args.watch, script, args.record, view, args.screenshot)


if __name__ == "__main__":
    os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
    run_command(main, "python -m flows.play")
