"""Freeway's runs in the results store (`dynplan.evaluation.store`, the same for every world): what a manifest and a
row hold, and the check that replays a row's recorded actions in a fresh emulator.

    <root>/runs/<run>/manifest.json   role, world `freeway-v1`, the emulator's settings, the learned technique's
                                      weights (SHA-256), every command that played the run
    <root>/runs/<run>/episodes.jsonl  one row per episode: its case (technique, world model, mode, seed of the NOOP
                                      starts' draw, episode, horizon), the weights' SHA-256 (learned), the NOOP
                                      start, score, knocks, steps, median decision ms, the actions and the code

The actions are run-length encoded (`encode_actions`: `U52N3D1…`, each action — N NOOP, U UP, D DOWN — and how
many steps in a row it was played): the game is deterministic, so a row's score, knocks and
steps follow from its mode, NOOP start and actions alone (`replay_check`), whatever played them — with sticky
actions (a run's settings), from those and the episode's seed, which draws the frames that repeat.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, model_validator

from dynplan.evaluation.store import expected_weights
from dynplan.evaluation.store_schema import FORMAT, ROLES, Invocation, RunLengthActions, StrictSchema, WorldModelEntry
from dynplan.world_parts import RunKind
from dynplan.worlds.freeway import WORLD
from dynplan.worlds.freeway.game import GAME_STEPS, MODES, ChickenGame, FreewayEpisode, emulator, emulator_seed

#: The techniques a row may name (`dynplan.worlds.freeway.evaluation.TECHNIQUES`).
TECHNIQUE_NAMES = ("oracle", "learned", "extrapolate", "zero", "up", "random")
#: The emulator of a run without sticky actions: deterministic, frameskip 4 (`settings` for another).
SETTINGS = {"repeat_action_probability": 0.0, "frameskip": 4}
#: The runs the results page shows, and the sticky actions each plays with (0.25: Machado et al.'s protocol).
STICKY_RUN = "sticky"
SHOWN_RUNS = {"evaluation": 0.0, STICKY_RUN: 0.25}


def settings(sticky: float) -> dict:
    """A run's emulator settings: frameskip 4, and sticky actions of probability `sticky`."""
    return {**SETTINGS, "repeat_action_probability": sticky}


Text = Annotated[str, Field(min_length=1)]
#: A row's actions run-length encoded, a letter an action (N NOOP, U UP, D DOWN).
ACTIONS_CODE = RunLengthActions("NUD")
encode_actions, decode_actions = ACTIONS_CODE.encode, ACTIONS_CODE.decode


Count = Annotated[int, Field(ge=0)]


class Settings(StrictSchema):
    """What every row of a run depends on besides its case: the emulator's options."""

    repeat_action_probability: Annotated[float, Field(ge=0.0, le=1.0)]
    frameskip: Literal[4]


class FreewayManifest(StrictSchema):
    """A Freeway run's `manifest.json`."""

    format: Literal[FORMAT]
    name: Annotated[str, Field(pattern=r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,99}$")]
    role: Literal[ROLES]
    world: Literal["freeway-v1"]
    settings: Settings
    world_models: dict[Text, WorldModelEntry]
    invocations: list[Invocation]


class FreewayRow(StrictSchema):
    """One line of a Freeway run's `episodes.jsonl`."""

    technique: Literal[TECHNIQUE_NAMES]
    model: Text | None
    mode: Annotated[int, Field(ge=0, le=len(MODES) - 1)]
    seed: Annotated[int, Field(ge=0, le=2**31)]
    episode: Annotated[int, Field(ge=0, le=999)]
    horizon: Annotated[int, Field(ge=1, le=64)]
    noop_start: Annotated[int, Field(ge=0, le=30)]
    score: Annotated[float, Field(ge=0.0, le=GAME_STEPS)]
    knocks: Annotated[int, Field(ge=0, le=GAME_STEPS)]
    steps: Annotated[int, Field(ge=1, le=GAME_STEPS)]
    decision_ms: Annotated[float, Field(ge=0.0)] | None
    actions: Annotated[str, Field(pattern=ACTIONS_CODE.pattern)]
    world_model_sha256: Text = None
    code_version: Text

    @model_validator(mode="after")
    def _one_action_a_step(self) -> FreewayRow:
        played = ACTIONS_CODE.steps(self.actions)
        if played != self.steps:
            raise ValueError(f"holds {played} actions for its {self.steps} steps")
        if (self.technique == "learned") != (self.model is not None):
            raise ValueError(f"technique {self.technique!r} {'needs' if self.model is None else 'takes no'} model")
        if not math.isclose(self.score, round(self.score)):
            raise ValueError(f"score {self.score} is not a count of crossings")
        return self


STAGES = ("vqvae", "pixelcnn")

RUNS = RunKind(
    world=WORLD.id,
    manifest_schema=FreewayManifest,
    row_schema=FreewayRow,
    case_keys=("technique", "model", "mode", "seed", "episode", "horizon"),
    provenance_keys=("world_model_sha256",),
    result_keys=("noop_start", "score", "knocks", "steps", "decision_ms", "actions", "code_version"),
    expected=expected_weights,
)


#: The checkout: weights inside it are recorded relative to it, so a manifest reads the same on every machine.
_ROOT = Path(__file__).resolve().parents[3]


def weights_entry(model: str, model_dir: str | os.PathLike | None) -> dict:
    """What a manifest records of the world model `model` in `model_dir` (holding vqvae.pt and pixelcnn.pt; None:
    the committed weights): their SHA-256, joined, and the files."""
    from dynplan.models.weights import (
        weights_sha256,  # torch: imported by the work, not by `--help`
        world_model_paths,
    )

    paths = world_model_paths(model) if model_dir is None else [Path(model_dir, f"{s}.pt") for s in STAGES]
    shown = [str(p.resolve().relative_to(_ROOT)) if _ROOT in p.resolve().parents else str(p) for p in paths]
    return {"weights_sha256": "+".join(weights_sha256(p) for p in paths), "weights": shown}


#: A deterministic emulator of each mode and its state at the game's start, kept by each process that replays rows:
#: loading the game takes 0.1 s, a tenth of a replay; restoring its start takes 0.1 ms. Sticky replays each draw from
#: their own seed, so each loads its own.
_STARTS: dict[int, tuple] = {}


def _game(episode: FreewayEpisode) -> ChickenGame:
    """A game at the start of `episode`, in a fresh emulator or (no sticky actions) one restored to the start."""
    if episode.sticky:
        return ChickenGame(episode)
    if episode.mode not in _STARTS:
        real = emulator(episode.mode)
        _STARTS[episode.mode] = (real, real.cloneState())
    real, start = _STARTS[episode.mode]
    real.restoreState(start)
    return ChickenGame(episode, real)


def replay_key(row: Mapping, run_settings: Mapping = SETTINGS) -> tuple:
    """What a row's replay depends on: its mode, NOOP start and actions (and, with sticky actions, the seed its
    episode draws them from). Rows with the same key replay alike, so a check replays each key once."""
    sticky = (row["seed"], row["episode"]) if run_settings["repeat_action_probability"] else ()
    return (row["mode"], row["noop_start"], row["actions"], *sticky)


def replayed(row: Mapping, run_settings: Mapping = SETTINGS) -> tuple[float, int, int, bool]:
    """The score, knocks and steps of `row`'s actions played from its mode's NOOP start in a fresh emulator with its
    run's settings (sticky actions drawn from the episode's seed), and whether the game ended on the last."""
    sticky = run_settings["repeat_action_probability"]
    seed = emulator_seed(row["seed"], row["episode"]) if sticky else 0
    game = _game(FreewayEpisode(mode=row["mode"], noop_start=row["noop_start"], sticky=sticky, emulator_seed=seed))
    score, knocks, steps, done = 0.0, 0, 0, False
    actions = decode_actions(row["actions"])
    for action in actions:  # each one of the 3 (the encoding has no other letters)
        before = game.chicken
        score, steps = score + game.advance(action), steps + 1
        done = game.over()
        knocks += before.timer == 0 and game.chicken.knocked
        if done:
            break
    return score, int(knocks), steps, done and steps == len(actions)


def replay_check(row: Mapping, run_settings: Mapping = SETTINGS) -> str | None:
    """None when `row`'s actions, played again with its run's settings, give its score, knocks and steps and end
    the game on the last; else what differs."""
    return replay_problem(row, replayed(row, run_settings))


def replay_problem(row: Mapping, replay: tuple[float, int, int, bool]) -> str | None:
    """None when `replay` (`replayed`'s score, knocks, steps and end) is what `row` says; else what differs."""
    score, knocks, steps, ended = replay
    if (score, knocks, steps) == (row["score"], row["knocks"], row["steps"]) and ended:
        return None
    end = "" if ended else ", the game not ending on the last"
    said = f"{row['score']:g}, {row['knocks']}, {row['steps']}"
    return f"its actions replay to score {score:g}, {knocks} knocks, {steps} steps{end}; the row says {said}"
