"""`python -m flows.play --world freeway`: steer the chicken across the real game with the keyboard, or watch the
planner play it, with the lanes the planner sees k steps ahead beside the truth.

The game is turn-based here, as the planner plays it: each key press is one agent step of the emulator (and of its
NOOP shadow, the world without the chicken). The right-hand panels show, at every step, the true lanes k steps on
and the lanes the technique (--technique: oracle, the true future; learned, what Freeway's world model imagines;
zero, empty lanes) searches there, whoever plays.

Keys:
  W or UP           the chicken steps up
  X or DOWN         the chicken steps down
  S                 the chicken waits (NOOP)
  K                 the planner's horizon k: 4, 8, 16
  P                 the planner plays / you play
  SPACE             pause or resume the planner
  R                 restart the episode
  ESC               quit (with --record, the replay log is written first)
"""

from __future__ import annotations

import argparse
from collections.abc import Iterable, Sequence

import numpy as np

from dynplan.cli import Bounded, CommandParser, bounded
from dynplan.env.colors import colorize
from dynplan.env.freeway import FreewayEpisode, chicken_mask
from dynplan.evaluation.freeway import PLANNERS, world_model_for
from dynplan.evaluation.freeway_play import HORIZONS, FreewayPlay
from dynplan.files import atomic_path
from dynplan.models.checkpoint import CheckpointError
from dynplan.paths import PathArgument, PathKind
from dynplan.planning.chicken import ChickenSearch
from dynplan.render import error_image
from flows.window import PanelWindow, checked_window_options

#: Key name → the chicken's action (0 NOOP, 1 UP, 2 DOWN).
ACTION_KEYS = {"w": 1, "up": 1, "x": 2, "down": 2, "s": 0}


def lanes_with_chicken(state: FreewayPlay) -> np.ndarray:
    """The lanes now in colour, the chicken in white."""
    image = colorize(state.frame)
    image[np.flip(chicken_mask(state.frame.shape, state.chicken.y), axis=0)] = 255
    return image


class Window(PanelWindow):
    """The pygame window: the lanes now with the chicken, the true lanes k steps on, those the planner sees there,
    and their error."""

    def __init__(self, state: FreewayPlay, scale: int = 3):
        super().__init__(state.frame.shape, 4, scale, "dynplan play: Freeway", 110)
        self.state = state

    def draw(self, planner_plays: bool, paused: bool) -> None:
        s, k = self.state, self.state.search.horizon
        truth, seen = s.true_frame(k), s.look_ahead()[-1]
        self.screen.fill((20, 20, 24))
        self.blit(lanes_with_chicken(s), 0, "the lanes now")
        self.blit(colorize(truth), 1, f"true, t + {k}")
        self.blit(colorize(seen), 2, f"{s.technique} sees, t + {k}")
        self.blit(error_image(truth, seen, "freeway"), 3, "error (red: missed, blue: extra)")
        who = ("planner plays" + (" (paused)" if paused else "")) if planner_plays else "you play"
        state = "game over" if not s.running else ("knocked back" if s.chicken.knocked else "")
        lines = [
            f"t = {s.t}   score {s.score:g}   {who}   k = {k}   {state}",
            "W/UP: up   X/DOWN: down   S: wait   K: horizon   P: planner/you   SPACE: pause   R: restart",
        ]
        self.text(lines)
        self.pygame.display.flip()


def _handle(state: FreewayPlay, name: str, planner_plays: bool, paused: bool) -> tuple[bool, bool]:
    """One key press: its effect on the state; returns (planner_plays, paused)."""
    if name == "r":
        state.reset()
    elif name == "k":
        state.cycle_horizon()
    elif name == "p":
        planner_plays = not planner_plays
    elif name == "space":
        paused = not paused
    elif name in ACTION_KEYS and state.running and not planner_plays:
        state.step(ACTION_KEYS[name])
    return planner_plays, paused


def play(state: FreewayPlay, scale: int = 3, fps: float = 15.0, planner_plays: bool = False,
         script: Iterable[str] | None = None, record: str | None = None,
         screenshot: str | None = None) -> FreewayPlay:  # fmt: skip
    """Run the window until ESC or the window closes. `script`: key names fed in as real key events, one per frame
    (then the window quits) — how the tests play it headless; `screenshot`: save the window's last picture there."""
    import pygame

    window = Window(state, scale)
    clock, paused, keys = pygame.time.Clock(), False, None if script is None else list(script)
    try:
        while keys is None or keys:
            if keys is not None:
                pygame.event.post(pygame.event.Event(pygame.KEYDOWN, key=pygame.key.key_code(keys.pop(0))))
            events = pygame.event.get()
            names = [pygame.key.name(e.key) for e in events if e.type == pygame.KEYDOWN]
            if any(e.type == pygame.QUIT for e in events) or "escape" in names:
                break
            for name in names:
                planner_plays, paused = _handle(state, name, planner_plays, paused)
            if planner_plays and not paused and state.running:
                state.step(*state.planner_action())
            window.draw(planner_plays, paused)
            clock.tick(fps)
        if screenshot is not None:
            with atomic_path(screenshot, keep_suffix=True) as tmp:
                pygame.image.save(window.screen, str(tmp))
    finally:
        pygame.quit()
        if record is not None and state.turns:
            print(f"recorded {state.record(record)}")
    return state


def _parser() -> CommandParser:
    parser = CommandParser(prog="python -m flows.play --world freeway", description=__doc__,
                           formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    parser.add_argument("--world", choices=["freeway"], default="freeway", help="freeway")
    parser.add_argument("--mode", type=bounded(FreewayEpisode, "mode"), default=0, help="the game mode (0 … 7)")
    parser.add_argument("--noop-start", type=bounded(FreewayEpisode, "noop_start"), default=0,
                        help="NOOP steps before the episode starts (0 … 30)")  # fmt: skip
    parser.add_argument("--technique", default="learned", choices=PLANNERS,
                        help="the planner that plays (P) and whose lanes are shown (default learned)")  # fmt: skip
    parser.add_argument("--model-dir", type=PathArgument(PathKind.MODEL_FOLDER),
                        help="the learned technique's world model: a folder holding vqvae.pt and pixelcnn.pt "
                        "(default: the committed Freeway weights)")  # fmt: skip
    parser.add_argument("--watch", action="store_true", help="start with the planner playing")
    parser.add_argument("-k", "--horizon", type=bounded(ChickenSearch, "horizon"), default=8,
                        help=f"the planner's horizon (K cycles through {', '.join(map(str, HORIZONS))})")  # fmt: skip
    parser.add_argument("--record", type=PathArgument(PathKind.OUTPUT_FILE), default=None,
                        help="write what was played to this replay log (.mcap) at the end")  # fmt: skip
    parser.add_argument("--scale", type=int, default=3, choices=range(1, 9), metavar="1..8", help="pixels per pixel")
    parser.add_argument("--fps", type=Bounded(float, 0.01, 1000.0), default=15.0,
                        help="frames per second while the planner plays")  # fmt: skip
    parser.add_argument("--screenshot", type=PathArgument(PathKind.OUTPUT_FILE), default=None,
                        help="save the window's last picture to this PNG at the end")  # fmt: skip
    parser.add_argument("--script", default=None,
                        help="key names separated by commas, one per frame, then quit (headless runs)")  # fmt: skip
    return parser


def main(argv: Sequence[str] | None = None) -> FreewayPlay:
    parser = _parser()
    args = parser.parse_args(argv)
    if args.model_dir is not None and args.technique != "learned":
        parser.error(f"--model-dir: only with --technique learned (--technique {args.technique} reads no world model)")
    script = checked_window_options(parser, args)
    try:
        model = world_model_for(args.technique, args.model_dir)
        state = FreewayPlay(FreewayEpisode(mode=args.mode, noop_start=args.noop_start), args.technique, args.horizon,
                            model)  # fmt: skip
    except (CheckpointError, ValueError) as error:
        parser.exit(2, f"python -m flows.play: error: {error}\n")
    return play(state, args.scale, args.fps, args.watch, script, args.record, args.screenshot)
