"""Measure the chicken's sprite at every height from the emulator: the table
`dynplan.worlds.freeway.game.sprite_hit` reads (`dynplan/worlds/freeway/chicken.npy`).

A car knocks the chicken back when one of its pixels meets one of the chicken's on the screen (the console's
collision latch), and the game reads the latch on the next frame: so a hit on emulator frame k is decided by the
chicken as drawn before k (its height then) and the cars drawn before k. The chicken's sprite changes with its
walk; this measures it directly, as the pixels where the real game's lanes differ from the NOOP shadow's within
the chicken's box while no car is in that box, and keeps, for each height, the shape seen most often. Heights whose
box reaches past the lanes get the union of all shapes: the cars' pixels beyond the lane frame (a bottom-lane car's
tyres reach one screen row below it) are unseen there, and measuring the box's part inside the lanes instead made
the oracle meet 9 cars at height 14 in one episode (mode 0, NOOP start 5: `python -m flows.replay --world freeway
LOG --noop-start 5` scored 32 against 34).

`python -m lab.freeway_sprites [--steps 16000]` rewrites the table and prints what it measured.
"""

from __future__ import annotations

import argparse
import io
from collections import Counter

import numpy as np

from dynplan.cli import Bounded, CommandParser, run_command
from dynplan.files import write_bytes_atomic
from dynplan.worlds.freeway import game as freeway
from dynplan.worlds.freeway.game import SPRITE_COLUMNS, SPRITE_ROWS, TOP_Y, emulator, lane_frame

TABLE = freeway.SPRITES


def measure(steps: int, seed: int = 0) -> tuple[np.ndarray, dict]:
    """(TOP_Y + 1, 8, 8) bool sprites by height (`SPRITES`' layout), and counts of what was seen."""
    votes: dict[int, Counter] = {}
    for mode in (0, 2):
        real, shadow = emulator(mode), emulator(mode)
        actions, rng, action = real.getMinimalActionSet(), np.random.default_rng(seed + mode), 0
        for frame in range(steps):
            if frame % freeway.FRAMESKIP == 0:
                action = actions[int(rng.choice(3, p=[0.2, 0.6, 0.2]))]
            real.act(action)
            shadow.act(actions[0])
            y = int(real.getRAM()[freeway.CHICKEN_Y_RAM])
            if not (y + SPRITE_ROWS[0] >= 0 and y + SPRITE_ROWS[1] <= freeway.LANE_HEIGHT):
                continue  # the box reaches past the lanes
            box = (slice(y + SPRITE_ROWS[0], y + SPRITE_ROWS[1]), SPRITE_COLUMNS)
            seen, road = lane_frame(real.getScreen())[box], lane_frame(shadow.getScreen())[box]
            if np.isin(road, freeway.ROAD_VALUES).all():
                votes.setdefault(y, Counter())[(seen != road).tobytes()] += 1
    shapes = {y: np.frombuffer(c.most_common(1)[0][0], bool).reshape(8, 8) for y, c in votes.items()}
    union = np.any(np.stack(list(shapes.values())), axis=0)
    table = np.stack([shapes.get(y, union) for y in range(TOP_Y + 1)])
    return table, {"heights seen": len(shapes), "with more than one shape": sum(len(c) > 1 for c in votes.values())}


def main(argv: list[str] | None = None) -> dict:
    parser = CommandParser(prog="python -m lab.freeway_sprites", description=__doc__,
                           formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    parser.add_argument("--steps", type=Bounded(int, 1000, 1_000_000), default=16_000, help="emulator frames a mode")
    args = parser.parse_args(argv)
    table, counts = measure(args.steps)
    buffer = io.BytesIO()
    np.save(buffer, table)
    write_bytes_atomic(TABLE, buffer.getvalue())
    print(f"{TABLE}: {counts}")
    return counts


if __name__ == "__main__":
    run_command(main, "python -m lab.freeway_sprites")
