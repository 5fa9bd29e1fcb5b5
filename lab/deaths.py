"""Why agents die: every death of an evaluated row replayed and given a cause.

An evaluated episode is deterministic given its case (recorded world, planner seed, sampling seed), so a death
can be replayed exactly to look at the last decision: what the forward model predicted for the frame the agent
died on, against the frame it was and the frame before. Causes, in the order they are tested:

- `off_grid`: the agent left the world.
- `foreseen`: the prediction showed an obstacle on the pixel the agent moved to (the search chose it anyway).
- `spawned`: the obstacle that killed was not on the road one step earlier (a new arrival at the lane's edge):
  no prediction from the past frames can show it, except as one of several sampled futures.
- `displaced`: the prediction has the obstacle in that lane, near its true place, but not on the agent's pixel
  (a sub-pixel phase or a length guessed wrong).
- `lost`: the obstacle was there a step earlier and the prediction shows nothing of it nearby (it vanished).

`python -m lab.deaths --technique samples5 --model default --agent-speed 1.0 --out FILE.json`
"""

from __future__ import annotations

import argparse
import json
from collections import Counter
from dataclasses import dataclass

import numpy as np

from dynplan.cli import CommandParser, run_command
from dynplan.data.collect import log_path
from dynplan.env.config import FREE, GOAL_VALUE
from dynplan.evaluation.agent import AgentSpec
from dynplan.evaluation.cases import ROLLOUT_STEPS, Case
from dynplan.evaluation.protocol import case_agent
from dynplan.evaluation.store import PROVENANCE_KEYS, provenance_of
from dynplan.evaluation.techniques import TECHNIQUES
from dynplan.files import write_bytes_atomic
from dynplan.logs.reader import read_episode_log
from dynplan.models.caution import Caution
from dynplan.models.registry import models_of
from dynplan.planning.episode import run_episode
from dynplan.world import DEFAULT_WORLD

CAUSES = ("off_grid", "foreseen", "spawned", "displaced", "lost")
#: Columns an obstacle can move in one step (the fastest class moves 2.3 px/step, drawn at the rounded position).
REACH = 3


def _obstacles(row: np.ndarray) -> np.ndarray:
    return (row != FREE) & (row != GOAL_VALUE)


def _run_around(mask: np.ndarray, x: int) -> tuple[int, int]:
    """The [start, stop) columns of the run of True in `mask` that contains column x."""
    start, stop = x, x + 1
    while start > 0 and mask[start - 1]:
        start -= 1
    while stop < len(mask) and mask[stop]:
        stop += 1
    return start, stop


def classify_death(before: np.ndarray, after: np.ndarray, predicted: np.ndarray, position: tuple[int, int]) -> str:
    """The cause (one of `CAUSES`) of a death at rounded `position` (y, x) on world frame `after` (H, W), given
    the frame observed one step earlier (`before`) and the forward model's prediction of `after`."""
    y, x = position
    height, width = after.shape
    if not (0 <= y < height and 0 <= x < width):
        return "off_grid"
    if _obstacles(predicted[y, x : x + 1])[0]:
        return "foreseen"
    true_now = _obstacles(after[y])
    if not true_now[x]:
        raise ValueError(f"no obstacle at {position} in the frame the agent died on: not a collision")
    start, stop = _run_around(true_now, x)
    near = slice(max(start - REACH, 0), min(stop + REACH, width))
    if not _obstacles(before[y, near]).any():
        return "spawned"
    return "displaced" if _obstacles(predicted[y, near]).any() else "lost"


@dataclass
class Death:
    seed: int
    rollout_steps: int
    t: int
    position: tuple[int, int]
    cause: str


def replay_death(case: Case, log_dir: str, playouts: int = 100, model_dir: str | None = None,
                 caution: dict[str, float] | None = None) -> Death:  # fmt: skip
    """Replay a case whose recorded outcome is a death and classify it (raises if the replay does not die).
    `caution`: the settings the learned model played with (`recorded_caution` of its result)."""
    world = read_episode_log(log_path(log_dir, case.seed)).world()
    spec = AgentSpec(playouts=playouts, model_dir=model_dir, caution=dict(caution or {}))
    planner, model = case_agent(case, world, spec)
    last: dict = {}

    def remember(t: int, position: np.ndarray, prediction, decision) -> None:
        last.update(t=t, p=prediction)

    result = run_episode(world, planner, model, case.agent_speed, case.rollout_steps or 1, on_decision=remember)
    if result.outcome != "death":
        raise RuntimeError(f"{case.group}/seed{case.seed}: replay ended in {result.outcome!r}, recorded a death")
    t = last["t"]
    position = tuple(int(v) for v in np.round(result.track.position[-1]))
    predicted = last["p"].frames[0] if last["p"] is not None else np.zeros_like(world.frames[t])
    cause = classify_death(world.frames[t], world.frames[t + 1], predicted, position)
    return Death(case.seed, case.rollout_steps, t, position, cause)


def recorded_caution(record: dict) -> dict[str, float]:
    """The caution a result was played with: every setting it records, and off where it records none (a result
    records only the settings that were on, and none from before a setting existed). A ValueError for a result
    played with a setting this code does not have (docs/experiments.md): it cannot be replayed as it was played."""
    unknown = sorted(set(provenance_of(record)) - set(PROVENANCE_KEYS))
    if unknown:
        raise ValueError(f"the result of seed {record.get('seed')} was played with {', '.join(unknown)}, which this "
                         "code does not have (docs/experiments.md names the commit that does)")  # fmt: skip
    return {name: record.get(name, 0) for name in Caution.model_fields}


def death_causes(records: list[dict], log_dir: str = "datasets/eval_logs", model_dir: str | None = None) -> list[Death]:
    """Replay and classify the deaths among evaluation records (the per-episode result JSONs)."""
    from dynplan.progress import progress

    deaths = [r for r in records if r["outcome"] == "death"]
    return [
        replay_death(
            Case(r["technique"], r["agent_speed"], r["rollout_steps"], r["seed"], r.get("model")),
            log_dir,
            r["playouts"],
            model_dir,
            recorded_caution(r),
        )
        for r in progress(deaths, total=len(deaths), description="replay deaths")
    ]


def summarise(deaths: list[Death], played: Counter) -> list[dict]:
    """Per horizon: episodes played, deaths, and deaths per cause."""
    rows = []
    for k in sorted(played):
        causes = Counter(d.cause for d in deaths if d.rollout_steps == k)
        rows.append({"k": k, "episodes": played[k], "deaths": sum(causes.values()), **{c: causes[c] for c in CAUSES}})
    return rows


def main(argv: list[str] | None = None) -> list[dict]:
    from dynplan.evaluation.store import Run
    from dynplan.evaluation.table import load_results

    parser = CommandParser(prog="python -m lab.deaths", description=__doc__,
                           formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    parser.add_argument("--technique", default="samples5", choices=[n for n, t in TECHNIQUES.items() if t.search])
    parser.add_argument("--model", default="default", choices=models_of(DEFAULT_WORLD),
                        help="world model of a learned technique")  # fmt: skip
    parser.add_argument("--agent-speed", type=float, default=1.0)
    parser.add_argument("--rollout-steps", type=int, nargs="+", default=list(ROLLOUT_STEPS))
    parser.add_argument("--results-dir", default="datasets/results", help="the results store")
    parser.add_argument("--run", help="the run whose deaths to classify (default: Table 1's evaluation runs)")
    parser.add_argument("--log-dir", default="datasets/eval_logs")
    parser.add_argument("--out", help="write the per-death causes and the summary here (JSON)")
    args = parser.parse_args(argv)
    model = args.model if TECHNIQUES[args.technique].world_model else None
    results = Run(args.results_dir, args.run).current() if args.run else load_results(args.results_dir)
    records = [r for r in results
               if r["technique"] == args.technique and r.get("model") == model
               and r["agent_speed"] == args.agent_speed and r["rollout_steps"] in args.rollout_steps]  # fmt: skip
    if not records:
        parser.error(f"no results for {args.technique} (model {model}) at agent speed {args.agent_speed} "
                     f"under {args.results_dir}")  # fmt: skip
    deaths = death_causes(records, args.log_dir)
    rows = summarise(deaths, Counter(r["rollout_steps"] for r in records))
    print("| k | episodes | deaths | " + " | ".join(CAUSES) + " |")
    print("| --- " * (3 + len(CAUSES)) + "|")
    for row in rows:
        print("| " + " | ".join(str(row[key]) for key in ("k", "episodes", "deaths", *CAUSES)) + " |")
    if args.out:
        payload = {"technique": args.technique, "model": model, "agent_speed": args.agent_speed, "summary": rows,
                   "deaths": [d.__dict__ for d in deaths]}  # fmt: skip
        write_bytes_atomic(args.out, json.dumps(payload, indent=1).encode())
    return rows


if __name__ == "__main__":
    run_command(main, "python -m lab.deaths")
