"""What a store's arrays may hold, checked wherever their values are read to be trusted: `--verify`, training on
the frames and encoding them.

A checksum says that a chunk holds the bytes it was written with, not that those bytes are an episode: a frame
written through Zarr with a pixel value outside its world's, a seed outside the world's range or a goal off the
frame pass every checksum. Each check here returns why the values of one chunk (or read) are not what the array
holds (None: they are), naming the first bad value and where it is.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Sequence

import numpy as np

from dynplan.config import ConfigError
from dynplan.world import World

#: A check of values read from one array: why they are not what it holds (None: they are).
Check = Callable[[np.ndarray, int], "str | None"]


def pixel_check(values: Sequence[int]) -> Check:
    """A check that frames (episode, time, y, x), the first being episode `first`, hold only `values`."""
    allowed = np.zeros(256, bool)
    allowed[list(values)] = True
    shown = ", ".join(map(str, sorted(values)))

    def check(frames: np.ndarray, first: int) -> str | None:
        if frames.dtype != np.uint8:
            return f"holds {frames.dtype} frames, not uint8"
        bad = ~allowed[frames]
        if not bad.any():
            return None
        where = tuple(int(i) for i in np.argwhere(bad)[0])
        episode, rest = (first + where[0], where[1:]) if frames.ndim == 4 else (first, where)
        at = ", ".join(f"{name} {i}" for name, i in zip(("frame", "row", "column"), rest, strict=False))
        value = int(frames[where])
        return f"episode {episode} holds pixel value {value} at {at}, not one of the world's values [{shown}]"

    return check


def seed_check(low: int, high: int) -> Check:
    """A check that seeds, the first being episode `first`'s, lie in the world's [low, high]."""

    def check(seeds: np.ndarray, first: int) -> str | None:
        bad = np.nonzero((seeds < low) | (seeds > high))[0]
        if not len(bad):
            return None
        return f"episode {first + int(bad[0])} has seed {int(seeds[bad[0]])}, outside the world's [{low}, {high}]"

    return check


def goal_check(height: int, width: int) -> Check:
    """A check that goal tracks (episode, time, 2) are finite and on the height × width frame."""

    def check(goals: np.ndarray, first: int) -> str | None:
        inside = np.isfinite(goals) & (goals >= 0) & (goals <= np.array([height, width], float))
        bad = np.argwhere(~inside.all(axis=-1))
        if not len(bad):
            return None
        episode, t = int(bad[0][0]) + first, int(bad[0][1])
        y, x = goals[tuple(bad[0])]
        return f"episode {episode}'s goal at frame {t} is ({y:g}, {x:g}), not on the {height} × {width} frame"

    return check


def store_checks(entry: World, attributes: dict) -> dict[str, Check]:
    """The check of each array of a store of the world `entry` with these group attributes (its config, height and
    width; a config that is not the world's leaves the frames unchecked: the metadata's check reports it)."""
    checks: dict[str, Check] = {"seed": seed_check(*entry.seeds)}
    config = attributes.get("config")
    with contextlib.suppress(ConfigError):
        if isinstance(config, dict):  # else damaged metadata, which the metadata's check names
            checks["frames"] = pixel_check(entry.values(entry.config(config)))
    if isinstance(attributes.get("height"), int) and isinstance(attributes.get("width"), int):
        checks["goal"] = goal_check(attributes["height"], attributes["width"])
    return checks
