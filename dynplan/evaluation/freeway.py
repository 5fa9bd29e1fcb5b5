"""Freeway's evaluation: each technique plays the real game (the score is the emulator's, never the rule's).

An episode is a game mode and a NOOP start (drawn from a seed); the chicken is read from the game's RAM and the
world through the NOOP shadow. Techniques: `oracle` plans with the true future (the mode's recording from the
episode's start on), `learned` with the future a world model imagines from the frames observed (once a decision),
`zero` with lanes that hold no car after the frame now, `up` always plays UP and `random` draws each action
uniformly. One result file per episode (`RESULTS/RUN/mode<m>-seed<s>/<technique>-k<k>-e<i>.json`,
written atomically), so an interrupted evaluation resumes per episode.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from pydantic import Field

from dynplan.cli import InputError
from dynplan.config import Config
from dynplan.env.freeway import ROAD_VALUES, Chicken, FreewayEpisode, FreewayGame, FreewayStep, record_mode
from dynplan.env.worlds import FREEWAY
from dynplan.files import write_bytes_atomic
from dynplan.models.world_model import load_world_model
from dynplan.planning.chicken import ChickenSearch, plan_chicken
from dynplan.planning.forward import ForwardModel

TECHNIQUES = ("oracle", "learned", "zero", "up", "random")
#: Techniques that plan (the others' decisions take no search).
PLANNERS = ("oracle", "learned", "zero")
#: Frames a learned agent keeps of what it observed: more than any world model's context.
OBSERVED = 16


class FreewayPlan(Config):
    """Which episodes an evaluation plays: `episodes` NOOP starts of game `mode` drawn from `seed`."""

    mode: int = Field(0, ge=0, le=7, description="the game mode (its traffic)")
    episodes: int = Field(20, ge=1, le=1000, description="episodes of the mode")
    seed: int = Field(0, ge=0, le=2**31, description="seed of the NOOP starts' draw")

    def episode_list(self) -> list[FreewayEpisode]:
        """The episodes: NOOP starts drawn uniformly from 0 … 30 with the seed and the mode."""
        starts = np.random.default_rng([self.seed, self.mode]).integers(0, 31, self.episodes)
        return [FreewayEpisode(mode=self.mode, noop_start=int(n)) for n in starts]


@dataclass(frozen=True)
class FreewayResult:
    """One episode played: the game's score, the times a car knocked the chicken back, the steps played and the
    median milliseconds of a decision (the search's; None for a technique that does not search)."""

    technique: str
    mode: int
    noop_start: int
    episode: int
    horizon: int
    score: float
    knocks: int
    steps: int
    decision_ms: float | None

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


#: The modes the world model never trains on (`dynplan.env.worlds.FREEWAY`).
FREEWAY_HELD_OUT = FREEWAY.held_out_seeds
#: The world-model configuration a learned agent imagines Freeway's lanes with (`dynplan.models.registry`).
MODEL = "freeway"


def world_model_for(technique: str, model_dir: str | os.PathLike | None = None) -> ForwardModel | None:
    """The world model `technique` plans with: for `learned`, Freeway's (trained into `model_dir`, holding
    `vqvae.pt` and `pixelcnn.pt`; else its committed weights); None for the others."""
    return load_world_model(model_dir, MODEL) if technique == "learned" else None


def searched_frames(observed: list[np.ndarray], search: ChickenSearch, future: np.ndarray | None = None,
                    model: ForwardModel | None = None) -> np.ndarray:  # fmt: skip
    """The lanes a planner searches at a decision: the frame now (the last `observed`) and the k after it — the
    true `future` (the oracle: the recording from the frame now on), the ones `model` imagines from the observed
    frames, or (neither) lanes that hold no car."""
    if future is not None:
        return future[: search.horizon + 1]
    if model is not None:
        ahead = model.predict(np.stack(observed[-OBSERVED:]), search.horizon).frames
    else:
        ahead = np.full((search.horizon, *observed[-1].shape), ROAD_VALUES[0], np.uint8)
    return np.concatenate([observed[-1][None], ahead])


def check_technique(technique: str, model: ForwardModel | None) -> None:
    """A ValueError unless `technique` is one of `TECHNIQUES` and is given a world model exactly when learned."""
    if technique not in TECHNIQUES:
        raise ValueError(f"technique {technique!r} is not one of {', '.join(TECHNIQUES)}")
    if (technique == "learned") != (model is not None):
        needs = "needs a world model" if technique == "learned" else "takes no world model"
        raise ValueError(f"technique {technique!r} {needs}")


def play_turns(technique: str, episode: FreewayEpisode, search: ChickenSearch, seed: int = 0,
               model: ForwardModel | None = None) -> Iterator[Turn]:  # fmt: skip
    """Play `episode` of the real game with `technique`, one turn at a time, to the game's end; `model`: the world
    model a learned agent imagines the lanes with."""
    check_technique(technique, model)
    future = record_mode(episode.mode).frames[episode.noop_start :] if technique == "oracle" else None
    game, rng = FreewayGame(episode), np.random.default_rng(seed)
    observed, t = [game.world_frame()], 0
    while True:
        chicken, frames, ms, start = game.chicken, None, None, time.perf_counter()
        if technique in PLANNERS:
            frames = searched_frames(observed, search, None if future is None else future[t:], model)
            action = plan_chicken(chicken, frames, search).action
            ms = (time.perf_counter() - start) * 1e3
        else:
            action = 1 if technique == "up" else int(rng.integers(0, 3))
        step = game.step(action)
        yield Turn(chicken, frames, action, ms, step)
        if step.done:
            return
        observed, t = [*observed[-OBSERVED + 1 :], step.frame], t + 1


def play_episode(technique: str, episode: FreewayEpisode, search: ChickenSearch, seed: int = 0,
                 model: ForwardModel | None = None) -> FreewayResult:  # fmt: skip
    """Play `episode` of the real game with `technique` to the game's end: its score, knocks, steps, decision ms."""
    score, knocks, steps, ms = 0.0, 0, 0, []
    for turn in play_turns(technique, episode, search, seed, model):
        score, steps = score + turn.step.reward, steps + 1
        knocks += turn.chicken.timer == 0 and turn.step.chicken.knocked
        ms += [] if turn.decision_ms is None else [turn.decision_ms]
    median = round(float(np.median(ms)), 3) if ms else None
    return FreewayResult(technique, episode.mode, episode.noop_start, -1, search.horizon, score, knocks, steps, median)


def result_path(results: str | os.PathLike, run: str, technique: str, plan: FreewayPlan, horizon: int,
                index: int) -> Path:  # fmt: skip
    """Where the result of episode `index` of `plan` played by a technique at a horizon lives in a run."""
    return Path(results, run, f"mode{plan.mode}-seed{plan.seed}", f"{technique}-k{horizon}-e{index:03d}.json")


def evaluate_episode(results: str | os.PathLike, run: str, technique: str, plan: FreewayPlan, index: int,
                     search: ChickenSearch, model: ForwardModel | None = None) -> FreewayResult:  # fmt: skip
    """Episode `index` of `plan` played by `technique` (with `model`, when learned) and written to the run, unless
    the run already holds it."""
    path = result_path(results, run, technique, plan, search.horizon, index)
    if path.is_file():
        return read_result(path)
    episode = plan.episode_list()[index]
    played = play_episode(technique, episode, search, plan.seed * 1000 + index, model)
    result = FreewayResult(**{**played.to_dict(), "episode": index})
    write_bytes_atomic(path, (json.dumps(result.to_dict(), sort_keys=True) + "\n").encode())
    return result


def read_result(path: str | os.PathLike) -> FreewayResult:
    """One episode's result file; an InputError naming the file if it is not one."""
    try:
        return FreewayResult(**json.loads(Path(path).read_text()))
    except (OSError, ValueError, TypeError) as error:
        raise InputError(f"{path}: not a Freeway result ({error}); delete it to play the episode again") from None


def read_run(results: str | os.PathLike, run: str) -> list[FreewayResult]:
    """Every episode result of a run, in file order."""
    return [read_result(p) for p in sorted(Path(results, run).glob("mode*/*.json"))]


def summarise(rows: list[FreewayResult]) -> list[dict]:
    """Per (mode, technique, horizon): episodes, mean score ± std, knocks an episode, median decision ms."""
    groups: dict[tuple, list[FreewayResult]] = {}
    for row in rows:
        groups.setdefault((row.mode, row.technique, row.horizon), []).append(row)
    order = {name: i for i, name in enumerate(TECHNIQUES)}
    summary = []
    for (mode, technique, horizon), group in sorted(groups.items(), key=lambda g: (g[0][0], order[g[0][1]], g[0][2])):
        scores = np.array([r.score for r in group])
        ms = [r.decision_ms for r in group if r.decision_ms is not None]
        summary.append({"mode": mode, "technique": technique, "horizon": horizon, "episodes": len(group),
                        "score": round(float(scores.mean()), 2), "std": round(float(scores.std()), 2),
                        "knocks": round(float(np.mean([r.knocks for r in group])), 2),
                        "decision_ms": round(float(np.median(ms)), 3) if ms else None})  # fmt: skip
    return summary


#: The public scoreboard (Atari 100k, Freeway, mean score as published): agents that learn everything from 100 k
#: interactions, where dynplan's knows the chicken's rule and learns only the world from recorded episodes.
SCOREBOARD = {"random": 0.0, "human": 29.6, "SimPLe": 16.7, "TWM": 24.3, "IRIS": 31.1, "DreamerV3": 0.0,
              "STORM": 33.5, "DIAMOND": 33.3, "MuZero": 21.8, "EfficientZero": 21.8, "BBF": 25.5}  # fmt: skip
#: The command that plays the committed Freeway evaluation.
EVALUATION_COMMAND = "python -m flows.evaluate --world freeway --modes 0 4 --episodes 20 --seed 0 --horizon 8"


def results_section(results: str | os.PathLike, run: str = "evaluation") -> list[str]:
    """The results page's Freeway section from the run's result files (none if the run is not there)."""
    if not Path(results, run).is_dir():
        return []
    return results_table(read_run(results, run), EVALUATION_COMMAND, "two processes on 2 cores")


def results_table(results: list[FreewayResult], command: str, played: str) -> list[str]:
    """A Freeway section: a row per technique and horizon, a column per mode, the learned agent against the oracle
    and the scoreboard; `command` is the one that played the episodes, `played` how (the times' conditions)."""
    rows = summarise(results)
    modes = sorted({row["mode"] for row in rows})
    cells: dict[tuple[str, int], dict[int, dict]] = {}
    for row in rows:
        cells.setdefault((row["technique"], row["horizon"]), {})[row["mode"]] = row
    header = " | ".join(f"mode {m}" for m in modes)
    lines = ["## Atari Freeway", "",
             f"`{command}` (docs/worlds.md): the real game's score, mean ± std over the episodes (NOOP "
             "starts drawn from the seed), and knocks an episode; a decision's median ms, the prediction's and the "
             f"search's ({played}; `python -m dynplan.bench freeway` times one idle core).", "",
             f"| technique | {header} | ms |", f"|{' --- |' * (len(modes) + 2)}"]  # fmt: skip
    for (technique, horizon), by_mode in cells.items():
        shown = [f"{r['score']:g} ± {r['std']:g}, {r['knocks']:g}" if (r := by_mode.get(m)) else "" for m in modes]
        ms = " / ".join(f"{r['decision_ms']:g}" for r in by_mode.values() if r["decision_ms"] is not None)
        name = f"{technique} k = {horizon}" if technique in PLANNERS else technique
        lines.append(f"| {name} | {' | '.join(shown)} | {ms} |")
    board = " · ".join(f"{name} {score:g}" for name, score in SCOREBOARD.items())
    return [*lines, "", *_against_the_oracle(rows), f"Atari 100k scoreboard: {board}; those agents learn everything "
            "from 100 k interactions, dynplan's knows the chicken's rule and learns only the world.", ""]  # fmt: skip


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
        parts.append(
            f"mode {mode}{' (never trained on)' if held_out else ''}, k = {horizon}: learned "
            f"{learned['score']:g}, oracle {oracle['score']:g}, {gap:+g} (target {target}: {verdict})"
        )
    if not parts:
        return []
    return ["Learned against the oracle: " + "; ".join(parts) + ". On mode 0 the oracle at k = 8 scores 34 from NOOP "
            "starts up to 16 and 33 from later ones (fewer steps), so its mean over uniform starts is 33.55: a mean "
            "of 33.5 is the oracle's own, which a learned agent can at best tie.", ""]  # fmt: skip
