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

from dynplan.cli import InputError
from dynplan.config import Config, ConfigError
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


def first_frame_check(entry: World, config: Config, seeds: Sequence[int | None]) -> Check:
    """A check that each episode's first frame is what its seed records (`seeds[episode]`; None: unknown, unchecked):
    a checksum and the palette pass a chunk of another episode's frames, this does not. One frame an episode is
    recorded (about 1 ms; a world whose recording needs a package not installed is left unchecked)."""

    recorded: dict[int, np.ndarray | None] = {}  # seed → its first frame (None: it cannot be recorded here)

    def first_frame(seed: int) -> np.ndarray | None:
        if seed not in recorded:
            try:
                recorded[seed] = entry.record(config, seed, 1).frames[0]
            except (ImportError, InputError):  # the world's package missing, or a seed the seed check names
                recorded[seed] = None
        return recorded[seed]

    def check(frames: np.ndarray, first: int) -> str | None:
        for i in range(len(frames) if frames.ndim == 4 else 0):
            seed = seeds[first + i] if first + i < len(seeds) else None
            expected = None if seed is None else first_frame(int(seed))
            if expected is not None and not np.array_equal(frames[i, 0], expected):
                return f"episode {first + i}'s first frame is not what its seed {seed} records (another episode's?)"
        return None

    return check


def both(*checks: Check) -> Check:
    """The first problem any of `checks` finds."""
    return lambda values, first: next((p for c in checks if (p := c(values, first)) is not None), None)


def store_checks(entry: World, attributes: dict, seeds: Sequence[int | None] | None = None) -> dict[str, Check]:
    """The check of each array of a store of the world `entry` with these group attributes (its config, height and
    width; a config that is not the world's leaves the frames unchecked: the metadata's check reports it); given
    each episode's seed, also that each episode's frames are its seed's (`first_frame_check`)."""
    checks: dict[str, Check] = {"seed": seed_check(*entry.seeds)}
    config = attributes.get("config")
    with contextlib.suppress(ConfigError):
        if isinstance(config, dict):  # else damaged metadata, which the metadata's check names
            recording = entry.config(config)
            checks["frames"] = pixel_check(entry.values(recording))
            if seeds is not None:
                checks["frames"] = both(checks["frames"], first_frame_check(entry, recording, seeds))
    if isinstance(attributes.get("height"), int) and isinstance(attributes.get("width"), int):
        checks["goal"] = goal_check(attributes["height"], attributes["width"])
    return checks
