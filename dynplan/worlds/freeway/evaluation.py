"""Freeway's evaluation: each technique plays the real game (the score is the emulator's, never the rule's).

An episode is a game mode and a NOOP start (drawn from a seed); the chicken is read from the game's RAM and the world
through the NOOP shadow. Techniques: `oracle` plans with the true future (the mode's recording from the episode's start
on), `learned` with the future a world model imagines from the frames observed (once a decision), `extrapolate` with
each lane's cars moved on at their mean speed over the last four steps (`game.extrapolated`: a constant-speed world,
what a world model has to beat), `zero` with lanes that hold no car after the frame now, `up` always plays UP and
`random` draws each action uniformly. Each episode is a row of a run of the results store
(`dynplan.worlds.freeway.results`: its case, score, knocks, steps, median decision ms and actions), appended as it
finishes, so an interrupted evaluation resumes per episode and every score can be checked against the game by replaying
its actions.
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass

import numpy as np
from pydantic import Field

from dynplan.config import Config
from dynplan.evaluation.store import Run, code_version
from dynplan.planning.forward import ForwardModel, Prediction
from dynplan.planning.lockstep import step_together
from dynplan.worlds.freeway import WORLD
from dynplan.worlds.freeway.game import (
    ROAD_VALUES,
    Chicken,
    FreewayEpisode,
    FreewayGame,
    FreewayStep,
    emulator_seed,
    episode_seed,
    extrapolated,
    record_mode,
)
from dynplan.worlds.freeway.results import RUNS, STICKY_RUN, encode_actions
from dynplan.worlds.freeway.search import ChickenSearch, plan_chicken

TECHNIQUES = ("oracle", "learned", "extrapolate", "zero", "up", "random")
#: Techniques that plan (the others' decisions take no search).
PLANNERS = ("oracle", "learned", "extrapolate", "zero")
#: Steps of history the extrapolator reads a lane's speed over (once it has observed them; fewer before).
EXTRAPOLATED = 4
#: Frames a learned agent keeps of what it observed: more than any world model's context.
OBSERVED = 16


class FreewayPlan(Config):
    """Which episodes an evaluation plays: `episodes` NOOP starts of game `mode` drawn from `seed`."""

    mode: int = Field(0, ge=0, le=7, description="the game mode (its traffic)")
    episodes: int = Field(20, ge=1, le=1000, description="episodes of the mode")
    seed: int = Field(0, ge=0, le=2**31, description="seed of the NOOP starts' draw")
    sticky: float = Field(0.0, ge=0.0, le=1.0, description="the game's sticky actions (0: none)")

    def episode_list(self) -> list[FreewayEpisode]:
        """The episodes: NOOP starts drawn uniformly from 0 … 30 with the seed and the mode; with sticky actions,
        each game's frames repeat as its own seed draws them."""
        starts = np.random.default_rng([self.seed, self.mode]).integers(0, 31, self.episodes)
        return [self.episode(i, int(n)) for i, n in enumerate(starts)]

    def episode(self, index: int, noop_start: int) -> FreewayEpisode:
        """Episode `index`, from NOOP start `noop_start`."""
        seed = emulator_seed(self.seed, index) if self.sticky else 0
        return FreewayEpisode(mode=self.mode, noop_start=noop_start, sticky=self.sticky, emulator_seed=seed)


@dataclass(frozen=True)
class FreewayResult:
    """One episode played: the game's score, the times a car knocked the chicken back, the steps played, the
    median milliseconds of a decision (the search's; None for a technique that does not search) and the actions,
    one digit a step (a row of the store holds them run-length encoded, `results.encode_actions`)."""

    technique: str
    mode: int
    noop_start: int
    episode: int
    horizon: int
    score: float
    knocks: int
    steps: int
    decision_ms: float | None
    actions: str = ""

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class Turn:
    """One step played: the chicken before it, the lanes the planner searched (the frame now and the k it predicted;
    None for a technique that does not plan), the action, the decision's milliseconds (the prediction's and the
    search's; None likewise) and the step."""

    chicken: Chicken
    frames: np.ndarray | None
    action: int
    decision_ms: float | None
    step: FreewayStep


#: The modes the world model never trains on (`dynplan.worlds.freeway.WORLD`).
FREEWAY_HELD_OUT = WORLD.held_out_seeds
#: The world-model configuration a learned agent imagines Freeway's lanes with (`dynplan.models.registry`).
MODEL = "freeway"


def world_model_for(technique: str, model_dir: str | os.PathLike | None = None) -> ForwardModel | None:
    """The world model `technique` plans with: for `learned`, Freeway's (trained into `model_dir`, holding
    `vqvae.pt` and `pixelcnn.pt`; else its committed weights); None for the others."""
    from dynplan.models.world_model import load_world_model  # torch: imported by the work, not by `--help`

    return load_world_model(model_dir, MODEL) if technique == "learned" else None


def searched_frames(
    observed: list[np.ndarray],
    search: ChickenSearch,
    technique: str,
    future: np.ndarray | None = None,
    model: ForwardModel | None = None,
    ahead: np.ndarray | None = None,
) -> np.ndarray:
    """The lanes `technique` searches at a decision: the frame now (the last `observed`) and the k after it — the
    true `future` (the oracle: the recording from the frame now on), the ones `model` imagines from the observed
    frames (learned; or `ahead`, when they were predicted with others'), the lanes moved on at their recent speeds
    (extrapolate; the frame now held still before a second frame is observed), or lanes that hold no car (zero)."""
    if technique == "oracle":
        return future[: search.horizon + 1]
    now = observed[-1]
    if technique == "learned":
        if ahead is None:
            ahead = model.predict(np.stack(observed[-OBSERVED:]), search.horizon).frames
    elif technique == "extrapolate":
        history = np.stack(observed[-EXTRAPOLATED - 1 :])
        ahead = extrapolated(history, search.horizon) if len(history) > 1 else np.repeat(now[None], search.horizon, 0)
    else:
        ahead = np.full((search.horizon, *now.shape), ROAD_VALUES[0], np.uint8)
    return np.concatenate([now[None], ahead])


def check_technique(technique: str, model: ForwardModel | None) -> None:
    """A ValueError unless `technique` is one of `TECHNIQUES` and is given a world model exactly when learned."""
    if technique not in TECHNIQUES:
        raise ValueError(f"technique {technique!r} is not one of {', '.join(TECHNIQUES)}")
    if (technique == "learned") != (model is not None):
        needs = "needs a world model" if technique == "learned" else "takes no world model"
        raise ValueError(f"technique {technique!r} {needs}")


class _Game:
    """One episode of a lockstep batch (`LockstepEpisode`): the real game, what the chicken observed, its random
    stream and its true future (the oracle's), and the turn it played last."""

    def __init__(self, lockstep: Lockstep, episode: FreewayEpisode, seed: int, future: np.ndarray | None) -> None:
        self.lockstep, self.game, self.rng, self.future = (
            lockstep,
            FreewayGame(episode),
            np.random.default_rng(seed),
            future,
        )
        self.model = lockstep.model
        self.frames, self.t, self.turn = [self.game.world_frame()], 0, None

    def observed(self) -> np.ndarray:
        return np.stack(self.frames[-OBSERVED:])

    def asks(self) -> int:
        return self.lockstep.search.horizon

    def advance(self, prediction: Prediction | None, share_ms: float) -> bool:
        """Decide (a planner: on the lanes its technique searches, `prediction`'s for learned) and step."""
        technique, search, rng = self.lockstep.technique, self.lockstep.search, self.rng
        start, frames, ms = time.perf_counter(), None, None
        if technique in PLANNERS:
            future = None if self.future is None else self.future[self.t :]
            ahead = None if prediction is None else prediction.frames
            frames = searched_frames(self.frames, search, technique, future, ahead=ahead)
            action = plan_chicken(self.game.chicken, frames, search).action
            ms = share_ms + (time.perf_counter() - start) * 1e3
        else:
            action = 1 if technique == "up" else int(rng.integers(0, 3))
        chicken, step = self.game.chicken, self.game.step(action)
        self.turn = Turn(chicken, frames, action, ms, step)
        self.frames, self.t = [*self.frames[-OBSERVED + 1 :], step.frame], self.t + 1
        return not step.done


class Lockstep:
    """`episodes` of the real game played together by `technique`, episode i drawing its random actions from
    `seeds[i]`: each `advance` makes one decision in every episode still playing (`step_together`), the learned
    technique's lanes from one batched prediction of all of them, whose time is shared between them."""

    def __init__(
        self,
        technique: str,
        episodes: Sequence[FreewayEpisode],
        search: ChickenSearch,
        seeds: Sequence[int],
        model: ForwardModel | None = None,
    ) -> None:
        check_technique(technique, model)
        if len(seeds) != len(episodes):
            raise ValueError(f"Lockstep: {len(episodes)} episodes and {len(seeds)} seeds")
        self.technique, self.search, self.model = technique, search, model
        recorded = {m: record_mode(m).frames for m in {e.mode for e in episodes}} if technique == "oracle" else {}
        futures = [recorded[e.mode][e.noop_start :] if recorded else None for e in episodes]
        self.games = [_Game(self, *each) for each in zip(episodes, seeds, futures, strict=True)]
        self.playing = list(range(len(episodes)))

    def advance(self) -> list[tuple[int, Turn]]:
        """One step of every episode still playing: (episode, its turn), in episode order."""
        playing = self.playing
        still = step_together([self.games[i] for i in playing])
        self.playing = [i for i, plays in zip(playing, still, strict=True) if plays]
        return [(i, self.games[i].turn) for i in playing]


def play_turns(
    technique: str, episode: FreewayEpisode, search: ChickenSearch, seed: int = 0, model: ForwardModel | None = None
) -> Iterator[Turn]:
    """Play `episode` of the real game with `technique`, one turn at a time, to the game's end (a lockstep of one);
    `model`: the world model a learned agent imagines the lanes with."""
    lockstep = Lockstep(technique, [episode], search, [seed], model)
    while lockstep.playing:
        yield lockstep.advance()[0][1]


class Tally:
    """What an episode's turns scored so far, kept as they are played (a game's turns hold its frames): score,
    knocks, steps, the decisions' ms and the actions."""

    def __init__(self) -> None:
        self.score, self.knocks, self.ms, self.actions = 0.0, 0, [], []

    def add(self, turn: Turn) -> None:
        self.score += float(turn.step.reward)
        self.knocks += int(turn.chicken.timer == 0 and turn.step.chicken.knocked)
        if turn.decision_ms is not None:
            self.ms.append(turn.decision_ms)
        self.actions.append(str(turn.action))

    def result(self, technique: str, episode: FreewayEpisode, horizon: int) -> FreewayResult:
        median = round(float(np.median(self.ms)), 3) if self.ms else None
        actions = "".join(self.actions)
        return FreewayResult(
            technique,
            episode.mode,
            episode.noop_start,
            -1,
            horizon,
            self.score,
            self.knocks,
            len(actions),
            median,
            actions,
        )


def play_episodes(
    technique: str,
    episodes: Sequence[FreewayEpisode],
    search: ChickenSearch,
    seeds: Sequence[int],
    model: ForwardModel | None = None,
) -> Iterator[tuple[int, FreewayResult]]:
    """Play `episodes` of the real game together with `technique` (`Lockstep`), to each game's end: (episode, its
    score, knocks, steps, decision ms and actions) as each ends."""
    lockstep = Lockstep(technique, episodes, search, seeds, model)
    tallies = [Tally() for _ in episodes]
    while lockstep.playing:
        for i, turn in lockstep.advance():
            tallies[i].add(turn)
            if turn.step.done:
                yield i, tallies[i].result(technique, episodes[i], search.horizon)


def play_episode(
    technique: str, episode: FreewayEpisode, search: ChickenSearch, seed: int = 0, model: ForwardModel | None = None
) -> FreewayResult:
    """Play `episode` of the real game with `technique` to the game's end: its score, knocks, steps, decision ms
    and actions."""
    return next(play_episodes(technique, [episode], search, [seed], model))[1]


def result_of(turns: list[Turn], technique: str, episode: FreewayEpisode, horizon: int) -> FreewayResult:
    """What `turns` (an episode's, played by `technique`) scored: score, knocks, steps, decision ms and actions."""
    tally = Tally()
    for turn in turns:
        tally.add(turn)
    return tally.result(technique, episode, horizon)


def case_of(technique: str, plan: FreewayPlan, index: int, horizon: int) -> dict:
    """The case of episode `index` of `plan` played by `technique` at `horizon`, as a run's row names it."""
    model = MODEL if technique == "learned" else None
    return {
        "technique": technique,
        "model": model,
        "mode": plan.mode,
        "seed": plan.seed,
        "episode": index,
        "horizon": horizon,
    }


def evaluate_episodes(
    run: Run,
    technique: str,
    plan: FreewayPlan,
    indices: Sequence[int],
    search: ChickenSearch,
    model: ForwardModel | None = None,
) -> list[dict]:
    """Episodes `indices` of `plan` played together by `technique` (`Lockstep`; with `model`, when learned: the
    weights the run's manifest records), each appended to `run` as it ends — or the run's row of it, if it holds one
    played with the same weights. The rows in the order of `indices`."""
    sticky = run.manifest()["settings"]["repeat_action_probability"]
    if plan.sticky != sticky:
        raise ValueError(
            f"run {run.name!r} plays sticky actions of probability {sticky:g}, not the plan's {plan.sticky:g}"
        )
    cases = {i: case_of(technique, plan, i, search.horizon) for i in indices}
    provenance = run.expected(next(iter(cases.values()))) if cases else {}
    rows = {i: run.find(case, provenance) for i, case in cases.items()}
    missing = [i for i, row in rows.items() if row is None]
    if not missing:
        return [rows[i] for i in indices]
    episodes = plan.episode_list()
    seeds = [episode_seed(plan.seed, i) for i in missing]
    for j, played in play_episodes(technique, [episodes[i] for i in missing], search, seeds, model):
        rows[missing[j]] = row = {
            **cases[missing[j]],
            "noop_start": played.noop_start,
            "score": played.score,
            "knocks": played.knocks,
            "steps": played.steps,
            "decision_ms": played.decision_ms,
            "actions": encode_actions(played.actions),
            **{k: v for k, v in provenance.items() if v is not None},
            "code_version": code_version(),
        }
        run.append(row)
    return [rows[i] for i in indices]


def read_run(results: str | os.PathLike, run: str) -> list[dict]:
    """The rows of a run that count (`Run.current`), in the order played."""
    return Run(results, run, RUNS).current()


def summarise(rows: list[dict]) -> list[dict]:
    """Per (mode, technique, horizon): episodes, mean score ± std, knocks an episode, median decision ms."""
    groups: dict[tuple, list[dict]] = {}
    for row in rows:
        groups.setdefault((row["mode"], row["technique"], row["horizon"]), []).append(row)
    order = {name: i for i, name in enumerate(TECHNIQUES)}
    summary = []
    for (mode, technique, horizon), group in sorted(groups.items(), key=lambda g: (g[0][0], order[g[0][1]], g[0][2])):
        scores = np.array([r["score"] for r in group])
        ms = [r["decision_ms"] for r in group if r["decision_ms"] is not None]
        summary.append(
            {
                "mode": mode,
                "technique": technique,
                "horizon": horizon,
                "episodes": len(group),
                "score": round(float(scores.mean()), 2),
                "std": round(float(scores.std()), 2),
                "knocks": round(float(np.mean([r["knocks"] for r in group])), 2),
                "decision_ms": round(float(np.median(ms)), 3) if ms else None,
            }
        )
    return summary


#: The public scoreboard (Atari 100k, Freeway, mean score as published): agents that learn everything from 100 k
#: interactions, where dynplan's knows the chicken's rule and learns only the world from recorded episodes.
SCOREBOARD = {
    "random": 0.0,
    "human": 29.6,
    "SimPLe": 16.7,
    "TWM": 24.3,
    "IRIS": 31.1,
    "DreamerV3": 0.0,
    "STORM": 33.5,
    "DIAMOND": 33.3,
    "MuZero": 21.8,
    "EfficientZero": 21.8,
    "BBF": 25.5,
}
#: The command that plays the committed Freeway evaluation.
EVALUATION_COMMAND = "python -m flows.evaluate --world freeway --modes 0 4 --episodes 20 --seed 0 --horizon 8"


def results_section(results: str | os.PathLike, run: str = "evaluation") -> list[str]:
    """The results page's Freeway section from the run of the store at `results` (none if the run is not there)."""
    if not Run(results, run, RUNS).exists():
        return []
    sticky = Run(results, STICKY_RUN, RUNS)
    played = (sticky.current(), sticky.manifest()["settings"]["repeat_action_probability"]) if sticky.exists() else None
    return results_table(read_run(results, run), EVALUATION_COMMAND, "2 cores shared", played)


#: What a Freeway agent is given, and so what its score measures: the section's first paragraph.
GIVEN = (
    "Given: the chicken's rule, measured from the emulator (docs/worlds.md), the lanes of the game's NOOP shadow (the "
    "world without the chicken) and the chicken's state from RAM. The learned agent learns the lanes alone, from "
    "modes 0–3, 6 and 7 (mode 4's traffic, whose speeds change during the game, it never saw): its score measures "
    "its world model, against the oracle (the true lanes), the extrapolator (each lane's cars moved on at their speed "
    "over the last four steps), zero (no cars)."
)


def results_table(
    results: list[dict], command: str, played: str, sticky: tuple[list[dict], float] | None = None
) -> list[str]:
    """A Freeway section: what the agent is given, a row per technique and horizon, a column per mode (and per mode
    of the `sticky` run's rows, played with that probability of sticky actions), the learned agent against the oracle
    and the extrapolator, and the scoreboard beside those; `command` is the one that played the episodes, `played`
    how (the times' conditions)."""
    rows = summarise(results)
    with_sticky = []
    if sticky is not None:
        with_sticky = [
            f"*Sticky* columns: the same episodes, ALE's sticky actions (at each frame the last action repeats "
            f"with probability {sticky[1]:g}, drawn from the episode's seed; the planner does not model it): "
            f"the command above with `{STICKY_OPTIONS}`.",
            "",
        ]
    lines = [
        "## Atari Freeway",
        "",
        GIVEN,
        "",
        f"`{command}`: the game's score, mean ± std (NOOP starts drawn by the seed), and "
        "knocks an episode; a decision's median ms, prediction (an episode's share of its lockstep batch's) and "
        f"search ({played}; `python -m dynplan.bench freeway`: one idle core).",
        "",
        *with_sticky,
        *_table(rows, [] if sticky is None else summarise(sticky[0])),
    ]
    return [*lines, "", *_against_the_oracle(rows), *_beside_the_scoreboard(rows)]


def _table(rows: list[dict], sticky: list[dict]) -> list[str]:
    """A row per technique and horizon, a column per mode (then per mode with sticky actions): mean score ± std and
    knocks; the decisions' ms (without sticky actions)."""
    columns = [(False, m) for m in sorted({r["mode"] for r in rows})] + [
        (True, m) for m in sorted({r["mode"] for r in sticky})
    ]
    cells: dict[tuple[str, int], dict[tuple[bool, int], dict]] = {}
    for is_sticky, summary in ((False, rows), (True, sticky)):
        for row in summary:
            cells.setdefault((row["technique"], row["horizon"]), {})[(is_sticky, row["mode"])] = row
    header = " | ".join(f"{'sticky' if is_sticky else 'mode'} {m}" for is_sticky, m in columns)
    lines = [f"| technique | {header} | ms |", f"|{' --- |' * (len(columns) + 2)}"]
    for (technique, horizon), by_column in cells.items():
        shown = [
            f"{r['score']:g} ± {r['std']:.2g}, {r['knocks']:.3g}" if (r := by_column.get(c)) else "" for c in columns
        ]
        ms = " / ".join(
            f"{r['decision_ms']:.0f}" for (s, _), r in by_column.items() if not s and r["decision_ms"] is not None
        )
        name = f"{technique} k = {horizon}" if technique in PLANNERS else technique
        lines.append(f"| {name} | {' | '.join(shown)} | {ms} |")
    return lines


#: The options that play the same episodes with the game's sticky actions into the run `sticky`.
STICKY_OPTIONS = "--run sticky --techniques oracle learned extrapolate zero"


def _beside_the_scoreboard(rows: list[dict]) -> list[str]:
    """The public scoreboard, beside the differences it does not measure."""
    board = " · ".join(f"{name} {score:g}" for name, score in SCOREBOARD.items())
    return [
        f"Beside those differences only, the Atari 100k scoreboard (published means): {board}. Those agents learn "
        "everything from 100 k interactions, this one the lanes alone: the scoreboard places the game's scores, not "
        "the agents.",
        "",
    ]


#: The learned agent's targets: at least this mean on mode 0, and at most these points below the oracle on mode 0
#: and on the mode its world model never trained on.
TARGET_SCORE, TARGET_GAP, HELD_OUT_GAP = 33.5, 1.0, 2.0


def _against_the_oracle(rows: list[dict]) -> list[str]:
    """A paragraph: the learned agent's mean against the oracle's at the same horizon and the targets, per mode
    both played (mode 0's score target, the gap targets of a trained mode and of one never trained on)."""
    by = {(r["mode"], r["technique"], r["horizon"]): r for r in rows}
    parts = []
    for mode, _, horizon in sorted(key for key in by if key[1] == "learned"):
        learned, oracle = by[(mode, "learned", horizon)], by.get((mode, "oracle", horizon))
        if oracle is None:
            continue
        gap, held_out = round(learned["score"] - oracle["score"], 2), mode in FREEWAY_HELD_OUT
        allowed = HELD_OUT_GAP if held_out else TARGET_GAP
        short = [round(-gap - allowed, 2)] + ([round(TARGET_SCORE - learned["score"], 2)] if mode == 0 else [])
        target = f"≥ {TARGET_SCORE:g} and within {allowed:g}" if mode == 0 else f"within {allowed:g}"
        verdict = "met" if max(short) <= 0 else f"not met, by {max(short):g}"
        others = ("extrapolate", "zero")
        beside = [f"{name} {r['score']:g}" for name in others if (r := by.get((mode, name, horizon)))]
        parts.append(
            f"mode {mode}{' (never trained on)' if held_out else ''}, k = {horizon}: learned "
            f"{learned['score']:g}, oracle {oracle['score']:g}, {gap:+g} (target {target}: {verdict})"
            + (f"; {', '.join(beside)}" if beside else "")
        )
    if not parts:
        return []
    return [
        "Learned against the oracle: " + "; ".join(parts) + ". Mode 0's 33.5 is the oracle's own mean at k = 8 "
        "(34 from NOOP starts up to 16, 33 after: 33.55 over uniform starts), which a learned agent can at best tie.",
        "",
    ]
