"""Atari Freeway as a dynplan world: the NOOP shadow's lanes are the world, the real chicken the agent.

`game` plays the real game and its shadow in the Arcade Learning Environment (the `atari` extra, imported only when
a game is played) and holds the chicken's rule; `search` plans the chicken; `models` registers its world model;
`evaluation`, `replay`, `play`, `report` and `commands` are its evaluation on the real game, replay logs, the play
window's state, the pipeline report's section and its commands' options (`parts`: the `WorldParts` that name them).
"""

from __future__ import annotations

from dynplan.world import World
from dynplan.worlds.freeway import game


def _record(config, seed, n_frames) -> game.FreewayWorld:
    return game.record_mode(seed, n_frames)


def _rebuild(config, seed, frames, goal, agent_start) -> game.FreewayWorld:
    return game.FreewayWorld(config, seed, frames, None, agent_start)


WORLD = World(
    name="freeway",
    summary="Atari Freeway's lanes (154 × 152), the NOOP shadow of the game; no goal",
    config_type=game.FreewayConfig,
    recording=game.FreewayConfig(),
    seeds=(0, len(game.MODES) - 1),
    seed_is="the game mode",
    record=_record,
    rebuild=_rebuild,
    pixel_values=lambda config: dict(game.PIXEL_VALUES),
    has_goal=False,
    actions=game.ACTIONS,
    clear=game.ROAD_VALUES,
    parts="dynplan.worlds.freeway.parts:PARTS",
    models="dynplan.worlds.freeway.models",
    extra="atari",
    # modes 0–3 and 6–7 train the world model, 5 validates it, and 4 is never trained on: the evaluation's mode
    # that the model never saw (its speeds change during the game, as 5–7's do)
    validation_seeds=frozenset({5}),
    held_out_seeds=frozenset({4}),
)
