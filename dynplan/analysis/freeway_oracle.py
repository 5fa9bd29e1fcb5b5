"""How well a planner that knows Freeway's true future can play: the oracle's ceiling for the chicken's rule.

The world does not depend on the chicken, so the true future is the NOOP shadow's frames, recorded before the
episode is played. At each step an exact search over the chicken's rule (`dynplan.env.freeway.chicken_frames`,
over each step's frames as `step_frames` estimates them from the step-level frames) — every action sequence of the
horizon k, states that coincide merged — picks the action that crosses most, then ends highest, and the real
emulator plays it.

`python -m dynplan.analysis.freeway_oracle --mode 0 --noop-starts 0 7 21 --horizons 8 12 16`
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import asdict, dataclass

import numpy as np

from dynplan.cli import Bounded, CommandParser, bounded, run_command
from dynplan.config import field_help
from dynplan.env.freeway import Chicken, FreewayEpisode, FreewayGame, chicken_frames, step_frames


def true_future(episode: FreewayEpisode) -> np.ndarray:
    """The episode's world frames from the agent's start to the game's end, (T + 1, 154, 152)."""
    game = FreewayGame(episode)
    frames = [game.world_frame()]
    while not (step := game.step(0)).done:
        frames.append(step.frame)
    frames.append(step.frame)
    return np.stack(frames)


def drawn_frames(frames: np.ndarray) -> np.ndarray:
    """(T − 1, 4, H, W): for each step t, the lanes drawn before its four emulator frames (`step_frames`)."""
    return np.stack([step_frames(frames[t], frames[t + 1]) for t in range(len(frames) - 1)])


def best_action(chicken: Chicken, drawn: np.ndarray, t: int, k: int) -> int:
    """The first action of the best k-step plan from `chicken` at step t over the steps' `drawn` frames: most
    crossings, then, free of a car, highest (a knocked or stunned chicken counts 30 pixels lower)."""
    layer: dict[Chicken, tuple[float, int]] = {chicken: (0.0, 1)}
    for depth in range(min(k, len(drawn) - t)):
        following: dict[Chicken, tuple[float, int]] = {}
        for state, (reward, first) in layer.items():
            for action in (1, 0, 2):
                after, gained = chicken_frames(state, action, drawn[t + depth])
                value = (reward + gained, action if depth == 0 else first)
                if after not in following or value[0] > following[after][0]:
                    following[after] = value
        layer = following
    return max(layer.items(), key=lambda item: (item[1][0], _height(item[0])))[1][1]


def _height(chicken: Chicken) -> int:
    return chicken.y - (30 if chicken.knocked else 0)


@dataclass(frozen=True)
class OracleEpisode:
    """An episode the oracle played: the game's score, the cars that hit the chicken, median decision ms."""

    mode: int
    noop_start: int
    horizon: int
    score: float
    hits: int
    decision_ms: float


def play(episode: FreewayEpisode, horizon: int) -> OracleEpisode:
    """Play the real game with the oracle's search at `horizon`; the score is the emulator's."""
    drawn = drawn_frames(true_future(episode))
    game, t, score, hits, ms = FreewayGame(episode), 0, 0.0, 0, []
    while True:
        chicken = game.chicken
        start = time.perf_counter()
        action = best_action(chicken, drawn, t, horizon)
        ms.append((time.perf_counter() - start) * 1e3)
        step = game.step(action)
        hits += chicken.timer == 0 and step.chicken.knocked
        score, t = score + step.reward, t + 1
        if step.done:
            return OracleEpisode(episode.mode, episode.noop_start, horizon, score, hits,
                                 round(float(np.median(ms)), 3))  # fmt: skip


def main(argv: list[str] | None = None) -> list[dict]:
    parser = CommandParser(prog="python -m dynplan.analysis.freeway_oracle", description=__doc__,
                           formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    parser.add_argument("--mode", type=bounded(FreewayEpisode, "mode"), default=0,
                        help=field_help(FreewayEpisode, "mode"))  # fmt: skip
    parser.add_argument("--noop-starts", type=bounded(FreewayEpisode, "noop_start"), nargs="+", default=[0],
                        help=field_help(FreewayEpisode, "noop_start") + ", one episode each")  # fmt: skip
    parser.add_argument("--horizons", type=Bounded(int, 1, 64), nargs="+", default=[8], help="the search's k")
    parser.add_argument("--json", action="store_true", help="print the episodes as JSON")
    args = parser.parse_args(argv)
    rows = []
    for horizon in args.horizons:
        for noop_start in args.noop_starts:
            played = play(FreewayEpisode(mode=args.mode, noop_start=noop_start), horizon)
            rows.append(asdict(played))
            if not args.json:
                print(f"mode {played.mode} noop {played.noop_start:2d} k {horizon:2d}: "
                      f"score {played.score:g}, hits {played.hits}, {played.decision_ms:.2f} ms a decision",
                      flush=True)  # fmt: skip
    if args.json:
        print(json.dumps(rows))
    return rows


if __name__ == "__main__":
    run_command(main, "python -m dynplan.analysis.freeway_oracle")
