"""What Freeway's planner needs from a world model: simple predictors of the lanes, played on the real game.

Each predictor imagines the k lane frames after the frame now from what has been observed; the chicken's exact
search (`dynplan.worlds.freeway.search`) plans on them and the real emulator plays. `oracle` is the true future; `shift`
moves each lane's cars on by the shift they made between the last two observed frames (`lane_shifts`), step after
step, and `shift4` by their mean shift a step over the last four; `still` repeats the frame now. How far they get
is how much of the game a model of lanes moving at their recent speed captures — what a learned world model has to
reach first.

`python -m lab.freeway_predictors --modes 0 4 --noop-starts 0 9 21 --predictors shift shift4 still`
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from dynplan.cli import CommandParser, bounded, run_command
from dynplan.config import field_help
from dynplan.worlds.freeway.game import FreewayEpisode, FreewayGame, extrapolated, record_mode
from dynplan.worlds.freeway.search import ChickenSearch, plan_chicken

PREDICTORS = ("oracle", "shift", "shift4", "still")
#: Steps of history each predictor reads.
CONTEXT = {"shift": 1, "shift4": 4}


def shifted(observed: np.ndarray, k: int) -> np.ndarray:
    """(k, H, W): the last observed frame's lanes moved on by their mean shift per step over `observed`
    (`dynplan.worlds.freeway.game.extrapolated`, the product's `extrapolate` technique)."""
    return extrapolated(observed, k)


def play(episode: FreewayEpisode, predictor: str, search: ChickenSearch) -> dict:
    """Play `episode` of the real game planning on `predictor`'s lanes: the game's score and the knocks."""
    future = record_mode(episode.mode).frames[episode.noop_start :]
    game, observed, t, score, knocks = FreewayGame(episode), [future[0]], 0, 0.0, 0
    while True:
        now = observed[-1]
        if predictor == "oracle":
            frames = future[t : t + search.horizon + 1]
        elif predictor in CONTEXT and len(observed) > CONTEXT[predictor]:
            history = np.stack(observed[-CONTEXT[predictor] - 1 :])
            frames = np.concatenate([now[None], shifted(history, search.horizon)])
        else:
            frames = np.repeat(now[None], search.horizon + 1, axis=0)
        chicken = game.chicken
        step = game.step(plan_chicken(chicken, frames, search).action)
        knocks += chicken.timer == 0 and step.chicken.knocked
        score, t = score + step.reward, t + 1
        observed = [*observed[-4:], step.frame]
        if step.done:
            return {"mode": episode.mode, "noop_start": episode.noop_start, "predictor": predictor,
                    "horizon": search.horizon, "score": score, "knocks": int(knocks)}  # fmt: skip


def main(argv: list[str] | None = None) -> list[dict]:
    parser = CommandParser(prog="python -m lab.freeway_predictors", description=__doc__,
                           formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    parser.add_argument("--modes", type=bounded(FreewayEpisode, "mode"), nargs="+", default=[0], help="game modes")
    parser.add_argument("--noop-starts", type=bounded(FreewayEpisode, "noop_start"), nargs="+", default=[0, 9, 21],
                        help=field_help(FreewayEpisode, "noop_start") + ", one episode each")  # fmt: skip
    parser.add_argument("--predictors", nargs="+", choices=PREDICTORS, default=list(PREDICTORS))
    parser.add_argument("--horizon", type=bounded(ChickenSearch, "horizon"), default=8,
                        help=field_help(ChickenSearch, "horizon"))  # fmt: skip
    parser.add_argument("--json", action="store_true", help="print the episodes as JSON")
    args = parser.parse_args(argv)
    rows = []
    for mode in args.modes:
        for predictor in args.predictors:
            for noop_start in args.noop_starts:
                row = play(
                    FreewayEpisode(mode=mode, noop_start=noop_start), predictor, ChickenSearch(horizon=args.horizon)
                )
                rows.append(row)
                if not args.json:
                    print(f"mode {mode} {predictor:6s} noop {noop_start:2d}: score {row['score']:g}, "
                          f"{row['knocks']} knocks", flush=True)  # fmt: skip
    if args.json:
        print(json.dumps(rows))
    return rows


if __name__ == "__main__":
    run_command(main, "python -m lab.freeway_predictors")
