"""What a world brings above its frames (`WorldParts`), declared as types: the commands' world-specific halves, its
presets and evaluation plan, its pipeline stages, its benchmarks and what its runs of the results store hold
(`RunKind`; the store itself is `dynplan.evaluation.store`, the same for every world).

The flows are the same for every world: `flows.evaluate --world W` parses the options W's `EvaluateCommand` adds,
makes its request, plays its jobs as Prefect tasks and prints its summary; `flows.replay` and `flows.play` do the
same with `ReplayCommand` and `PlayCommand`, and `collect-train-eval` evaluates and reports through
`PipelineStages`. None of these imports Prefect: a world's package is library code. Every world takes this path,
the road's (`dynplan.worlds.road`) too.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from pydantic import BaseModel

from dynplan.config import Config


@dataclass(frozen=True)
class Recordings:
    """The recorded episodes an evaluation plays against: `episodes` seeds from `first_seed` in `folder` (the flow
    records those that are missing before any job starts)."""

    folder: str
    episodes: int
    first_seed: int


class EvaluateCommand(Protocol):
    """`flows.evaluate --world W`: the options, the request they make (`request_type`, checked before any flow
    machinery starts; it names its run, `run`), the recorded episodes it plays against (None: none, the world is
    played live), the run begun in the results store (its manifest records `command`) and the episodes it still
    has to play as jobs (each a Prefect task; a job is a dict of the world's own keys and `episodes`, how many it
    plays), one job played into the run, the summary of what the run holds (a table artifact keyed
    `<summary_key>-<run>`; taken again after every job, so a world that writes a table from it keeps it current),
    its lines, and the check of each row (`--check`: a line per row that does not hold)."""

    request_type: type[Config]
    summary_key: str

    def add_arguments(self, parser: argparse.ArgumentParser) -> None: ...

    def request(self, args: argparse.Namespace) -> Config: ...

    def recordings(self, request: Config) -> Recordings | None: ...

    def start(self, request: Config, command: str) -> list[dict]: ...

    def play(self, request: Config, job: dict) -> dict: ...

    def summary(self, request: Config) -> list[dict]: ...

    def describe(self, summary: list[dict]) -> list[str]: ...

    def check(self, request: Config) -> list[str]: ...


class ReplayCommand(Protocol):
    """`flows.replay --world W LOG`: the options, the request they make (inputs and outputs checked), the replay
    (a log for `flows.view`, its result as a dict) and the result in one line."""

    request_type: type[Config]

    def add_arguments(self, parser: argparse.ArgumentParser) -> None: ...

    def request(self, args: argparse.Namespace) -> Config: ...

    def replay(self, request: Config) -> dict: ...

    def describe(self, result: dict) -> str: ...


class PlayState(Protocol):
    """One interactive episode a play window shows: its panels (RGB images with titles, as many at every step),
    lines of text, the keys that choose the agent's actions, what the window's own keys do (restart, horizon, the
    planner's turn), a key of the world's own (`key`: True when it was one), and what it holds until the window
    closes (`close`: a live view)."""

    caption: str
    keys: Mapping[str, int]
    running: bool
    turns: Sequence

    def panels(self) -> list[tuple[np.ndarray, str]]: ...

    def status(self, planner_plays: bool, paused: bool) -> list[str]: ...

    def step(self, action: int, decision_ms: float | None = None) -> Any: ...

    def planner_action(self) -> tuple[int, float]: ...

    def reset(self) -> None: ...

    def cycle_horizon(self) -> int: ...

    def record(self, path: str | Path) -> Path: ...

    def key(self, name: str) -> bool: ...

    def close(self) -> None: ...


class PlayCommand(Protocol):
    """`flows.play --world W`: the options and the state they make (a ValueError or CheckpointError names a bad
    one); `scale` is the window's default pixels per frame pixel, `fps` its default frames a second while the
    planner plays."""

    scale: int
    fps: float

    def add_arguments(self, parser: argparse.ArgumentParser) -> None: ...

    def state(self, args: argparse.Namespace) -> PlayState: ...


class PipelineStages(Protocol):
    """A world's part of `collect-train-eval`: the evaluation requests a preset plays (each through its
    `EvaluateCommand`) and the report's results section (lines of Markdown; pictures written into `out`)."""

    def evaluations(self, preset: Config, work: Path) -> list[Config]: ...

    def report(self, preset: Config, work: Path, out: Path, command: str) -> list[str]: ...


@dataclass(frozen=True)
class RunKind:
    """What one world's runs hold: its id (`name-vN`), the schemas of a manifest and a row, the keys that identify
    a row's case, the provenance keys every row has (None where absent), the keys of how its episode went, what a
    manifest asks of a case's provenance (`expected`) and what in a row contradicts its manifest (`conflict`: a
    phrase naming the field, or None), which makes the row one its run cannot have written: refused, not skipped."""

    world: str
    manifest_schema: type[BaseModel]
    row_schema: type[BaseModel]
    case_keys: tuple[str, ...]
    provenance_keys: tuple[str, ...]
    result_keys: tuple[str, ...]
    expected: Callable[[Mapping, Mapping], dict]
    conflict: Callable[[Mapping, Mapping], str | None] = lambda manifest, row: None

    def case_key(self, row: Mapping) -> tuple:
        return tuple(row.get(k) for k in self.case_keys)

    def provenance_of(self, row: Mapping) -> dict:
        """The provenance a row records: `provenance_keys` (None where absent) and any other key that is neither
        its case nor its result — a setting recorded by code that had it, which a row played without it does not
        share."""
        named = {*self.case_keys, *self.result_keys, *self.provenance_keys}
        extra = {k: v for k, v in row.items() if k not in named}
        return {**{k: row.get(k) for k in self.provenance_keys}, **extra}

    def identity(self, row: Mapping) -> str:
        return json.dumps([self.case_key(row), self.provenance_of(row)], sort_keys=True)


@dataclass(frozen=True)
class WorldParts:
    """A world above its frames: its pipeline presets by name, the type of a preset's evaluation plan, its
    commands' world-specific halves, its pipeline stages, its benchmarks (`python -m dynplan.bench NAME`: name →
    "module:function", imported by the benchmarks alone, which are the lab's), the Foxglove layout of its replay
    logs (`layout`, the current app's dialect) and the same for the Studio 1.48 that `flows.view` serves
    (`studio_layout`; None: the road's, `dynplan/logs/layouts/`), its section of the
    results page (`python -m dynplan.evaluation.results --docs`) from its folder of the results store, and what
    its runs in that store hold (`runs`; None: the road's `ROAD_RUNS`, or no runs)."""

    presets: Mapping[str, Config] = field(default_factory=dict)
    evaluation_plan: type[Config] | None = None
    evaluate: EvaluateCommand | None = None
    replay: ReplayCommand | None = None
    play: PlayCommand | None = None
    pipeline: PipelineStages | None = None
    benches: Mapping[str, str] = field(default_factory=dict)
    layout: Path | None = None
    studio_layout: Path | None = None
    results_section: Callable[[Path], list[str]] | None = None
    runs: RunKind | None = None
