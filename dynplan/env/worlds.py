"""The worlds dynplan plans in, one registry entry each (docs/worlds.md says how to add one).

A world is a sequence of frames that does not depend on the agent. Its entry says how an episode of it is
recorded (the frames without the agent, from the world's config and the episode's seed), what its frames hold
(shape and pixel values by name), whether it has a goal track, and the agent's actions. Logs, frame stores and
commands read a world's entry and nothing else of it: the road world (`dynplan.env.road`) is the first entry,
Atari Freeway (`dynplan.env.freeway`, the `atari` extra) the second.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from dynplan.config import Config, ConfigError
from dynplan.env import freeway
from dynplan.env.agent import ACTION_ANGLES_DEG
from dynplan.env.config import FREE, GOAL_VALUE, RoadConfig, obstacle_classes
from dynplan.env.road import World, generate_world


class WorldConfig(Protocol):
    """What every world's config tells: its frame's size and the frames of a whole episode."""

    @property
    def height(self) -> int: ...

    @property
    def width(self) -> int: ...

    @property
    def max_steps(self) -> int: ...

    def model_dump(self) -> dict: ...


class Recording(Protocol):
    """One episode of a world without the agent, as a log records it: frames (T, H, W) uint8 with row 0 the
    bottom, the goal track (T, 2) (y, x) or None for a world without a goal, and where the agent starts (y, x)."""

    config: WorldConfig
    seed: int
    frames: np.ndarray
    goal: np.ndarray | None
    agent_start: np.ndarray


@dataclass(frozen=True)
class WorldEntry:
    """One world: its name, config type and the config a recording takes by default, the episodes' seeds (an
    inclusive range, and what a seed is), how an episode is recorded and rebuilt from a log, its pixel values by
    name, which of them are clear ground (no obstacle; the first is the background), whether it has a goal track,
    its actions, the package extra it needs (None: none), and the seeds of its validation episodes and of the
    episodes no model trains on (None: by a hash of the seed, `dynplan.data.datasets.is_validation`)."""

    name: str
    summary: str
    config_type: type[Config]
    recording: Config
    seeds: tuple[int, int]
    seed_is: str
    record: Callable[[Config, int, int | None], Recording]
    rebuild: Callable[[Config, int, np.ndarray, np.ndarray | None, np.ndarray], Recording]
    pixel_values: Callable[[Config], dict[str, int]]
    has_goal: bool
    actions: tuple[str, ...]
    clear: tuple[int, ...]
    extra: str | None = None
    validation_seeds: frozenset[int] | None = None
    held_out_seeds: frozenset[int] = frozenset()

    def config(self, values: dict | None = None) -> Config:
        """The world's config from a plain dict (a log's or a store's record), validated."""
        return self.config_type.from_dict(values or {})

    def check_seed(self, seed: int, what: str = "seed") -> int:
        """`seed`, if it names an episode of this world; otherwise a ConfigError naming the valid range."""
        lo, hi = self.seeds
        if not lo <= seed <= hi:
            raise ConfigError(f"{what}={seed} is invalid for the {self.name} world; valid range [{lo}, {hi}] "
                              f"({self.seed_is})")  # fmt: skip
        return seed

    def values(self, config: Config | None = None) -> tuple[int, ...]:
        """The pixel values of the world's frames (of `config`, else the recording default), ascending."""
        return tuple(sorted(set(self.pixel_values(config or self.recording).values())))

    @property
    def background(self) -> int:
        """The value of empty ground: what fills a frame padded to a model's grid."""
        return self.clear[0]


def road_pixel_values(config: RoadConfig) -> dict[str, int]:
    """The road's values by name: free road, the goal and each obstacle class of its width."""
    return {"free": FREE, "goal": GOAL_VALUE, **{c.name: c.value for c in obstacle_classes(config.width)}}


def _road_rebuild(config, seed, frames, goal, agent_start) -> World:
    return World(config, seed, frames, goal, agent_start)


def _freeway_record(config, seed, n_frames) -> freeway.FreewayWorld:
    return freeway.record_mode(seed, n_frames)


def _freeway_rebuild(config, seed, frames, goal, agent_start) -> freeway.FreewayWorld:
    return freeway.FreewayWorld(config, seed, frames, None, agent_start)


ROAD = WorldEntry(
    name="road", summary="the paper's world: lanes of traffic and a wall-bouncing goal, 48 × 48",
    config_type=RoadConfig, recording=RoadConfig(level=6, agent_speed=0.5), seeds=(0, 2**62),
    seed_is="the seed of the episode's random draws", record=generate_world, rebuild=_road_rebuild,
    pixel_values=road_pixel_values, has_goal=True,
    actions=tuple(f"heading {angle:g}°" for angle in ACTION_ANGLES_DEG), clear=(FREE, GOAL_VALUE),
)  # fmt: skip
FREEWAY = WorldEntry(
    name="freeway", summary="Atari Freeway's lanes (154 × 152), the NOOP shadow of the game; no goal",
    config_type=freeway.FreewayConfig, recording=freeway.FreewayConfig(), seeds=(0, len(freeway.MODES) - 1),
    seed_is="the game mode", record=_freeway_record, rebuild=_freeway_rebuild,
    pixel_values=lambda config: dict(freeway.PIXEL_VALUES), has_goal=False, actions=freeway.ACTIONS, extra="atari",
    clear=freeway.ROAD_VALUES,
    # modes 0–3 and 6–7 train the world model, 5 validates it, and 4 is never trained on: the evaluation's mode
    # that the model never saw (its speeds change during the game, as 5–7's do)
    validation_seeds=frozenset({5}), held_out_seeds=frozenset({4}),
)  # fmt: skip

#: Every world, by name; the first is the default.
WORLDS: dict[str, WorldEntry] = {entry.name: entry for entry in (ROAD, FREEWAY)}
DEFAULT_WORLD = ROAD.name


def world(name: str) -> WorldEntry:
    """The world called `name`; a ConfigError naming the worlds there are otherwise."""
    if name not in WORLDS:
        raise ConfigError(f"world {name!r} is not one of dynplan's worlds: {', '.join(WORLDS)}")
    return WORLDS[name]


def world_of(config: Config) -> WorldEntry:
    """The world whose config `config` is; a ConfigError naming the worlds' configs otherwise."""
    for entry in WORLDS.values():
        if isinstance(config, entry.config_type):
            return entry
    kinds = ", ".join(entry.config_type.__name__ for entry in WORLDS.values())
    raise ConfigError(f"a {type(config).__name__} is no world's config; the worlds' are {kinds}")
