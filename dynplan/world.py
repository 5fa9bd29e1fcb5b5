"""The worlds dynplan plans in: one `World` spec each, found through the entry-point group `dynplan.worlds`.

A world is a sequence of frames that does not depend on the agent. Its spec says how an episode of it is recorded (the
frames without the agent, from the world's config and the episode's seed), what its frames hold (shape and pixel values
by name), whether it has a goal track, the agent's actions, and where the rest of it lives: its `WorldParts`
(`dynplan.world_parts`: its presets, commands, pipeline stages, results and runs, layouts and benchmarks) and the module
that registers its world models, each imported only when a command uses it. Logs, frame stores and commands read a
world's spec and nothing else of it.

A package adds a world by naming its spec in its own `pyproject.toml`:

    [project.entry-points."dynplan.worlds"]
    myworld = "mypackage.world:WORLD"

Importing the registry imports no world; `world(name)` imports the one named (and a world's extra only when its
game is played). dynplan's own worlds are the packages of `dynplan.worlds`, the road the default; docs/worlds.md
says how to add one.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cache
from importlib.metadata import EntryPoint, entry_points
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from dynplan.config import Config, ConfigError

if TYPE_CHECKING:
    from dynplan.world_parts import WorldParts

#: The entry-point group a world's spec is registered under.
GROUP = "dynplan.worlds"
#: The world every command plays unless told another: the paper's.
DEFAULT_WORLD = "road"


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
class World:
    """One world: its name and version (logs and stores record both), its config type and the config a recording
    takes by default, the episodes' seeds (an inclusive range, and what a seed is), how an episode is recorded and
    rebuilt from a log, its pixel values by name, which of them are clear ground (no obstacle; the first is the
    background), whether it has a goal track, its actions, the package extra it needs (None: none), the seeds of
    its validation episodes and of the episodes no model trains on (None: by a hash of the seed,
    `dynplan.data.datasets.is_validation`), `parts`: where its `WorldParts` are ("module:attribute"), and `models`:
    the module that registers its world-model configurations (None: they are registered with the library's own).
    """

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
    parts: str
    models: str | None = None
    version: int = 1
    extra: str | None = None
    validation_seeds: frozenset[int] | None = None
    held_out_seeds: frozenset[int] = frozenset()

    @property
    def id(self) -> str:
        """The world's versioned id, `name-vN`: what results record of the world they were played in."""
        return f"{self.name}-v{self.version}"

    def config(self, values: dict | None = None) -> Config:
        """The world's config from a plain dict (a log's or a store's record), validated."""
        return self.config_type.from_dict(values or {})

    def check_seed(self, seed: int, what: str = "seed") -> int:
        """`seed`, if it names an episode of this world; otherwise a ConfigError naming the valid range."""
        lo, hi = self.seeds
        if not lo <= seed <= hi:
            raise ConfigError(
                f"{what}={seed} is invalid for the {self.name} world; valid range [{lo}, {hi}] ({self.seed_is})"
            )
        return seed

    def values(self, config: Config | None = None) -> tuple[int, ...]:
        """The pixel values of the world's frames (of `config`, else the recording default), ascending."""
        return tuple(sorted(set(self.pixel_values(config or self.recording).values())))

    @property
    def background(self) -> int:
        """The value of empty ground: what fills a frame padded to a model's grid."""
        return self.clear[0]

    def load(self) -> WorldParts:
        """The world's parts above its data (agent, techniques, models, presets, commands, report), imported now."""
        return resolve(self.parts)


@cache
def _specs() -> dict[str, str]:
    """Every registered world, name → "module:attribute" (dynplan's own are registered by its pyproject.toml)."""
    found = {point.name: point.value for point in entry_points(group=GROUP)}
    if DEFAULT_WORLD not in found:
        raise ConfigError(
            f"no world is registered under the entry points {GROUP!r}: install dynplan (pip install -e .)"
        )
    return found


def world_names() -> list[str]:
    """The registered worlds' names, the default first; none is imported."""
    names = list(_specs())
    return [DEFAULT_WORLD, *sorted(n for n in names if n != DEFAULT_WORLD)]


def world(name: str) -> World:
    """The world called `name`, imported on first use; a ConfigError naming the worlds there are otherwise."""
    if name not in _specs():
        raise ConfigError(f"world {name!r} is not one of dynplan's worlds: {', '.join(world_names())}")
    spec = resolve(_specs()[name])
    if not isinstance(spec, World) or spec.name != name:
        raise ConfigError(f"the entry point {GROUP}:{name} ({_specs()[name]}) is not a World named {name!r}")
    return spec


def world_of(config: Config) -> World:
    """The world whose config `config` is; a ConfigError naming the worlds' configs otherwise."""
    every = [world(name) for name in world_names()]
    for entry in every:
        if isinstance(config, entry.config_type):
            return entry
    kinds = ", ".join(entry.config_type.__name__ for entry in every)
    raise ConfigError(f"a {type(config).__name__} is no world's config; the worlds' are {kinds}")


def resolve(reference: str) -> Any:
    """The object a "module:attribute" reference names, imported as an entry point is (a world's spec, its parts,
    a benchmark)."""
    return EntryPoint(name=reference, value=reference, group=GROUP).load()
