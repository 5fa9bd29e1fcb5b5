"""Do Freeway's committed rows hold when played again the evaluation's way? Plays the committed run's episodes of a
technique and modes again, in lockstep (`evaluate_episodes`), into a fresh run of its own, and compares each row's
actions, score and knocks with the committed row's; prints the wall time per decision.

`python -m lab.freeway_lockstep_check --technique learned --modes 0 4 --out /tmp/lockstep-check`
"""

from __future__ import annotations

import argparse
import json
import time

import torch

from dynplan.cli import CommandParser, run_command
from dynplan.evaluation.store import Run
from dynplan.worlds.freeway.evaluation import MODEL, TECHNIQUES, FreewayPlan, evaluate_episodes, world_model_for
from dynplan.worlds.freeway.results import RUNS, SETTINGS, weights_entry
from dynplan.worlds.freeway.search import ChickenSearch

COMMITTED = "datasets/results/freeway"


def check(technique: str, mode: int, out: str) -> dict:
    """Mode `mode`'s 20 committed episodes of `technique` (seed 0, k = 8) played again into `out`."""
    run = Run(f"{out}/mode{mode}", "check", RUNS)
    models = {MODEL: weights_entry(MODEL, None)} if technique == "learned" else {}
    run.start("candidate", SETTINGS, models, "python -m lab.freeway_lockstep_check")
    start = time.perf_counter()
    plan, search = FreewayPlan(mode=mode, episodes=20, seed=0), ChickenSearch(horizon=8)
    rows = evaluate_episodes(run, technique, plan, list(range(20)), search, world_model_for(technique))
    seconds = time.perf_counter() - start
    committed = {
        (r["technique"], r["episode"]): r for r in Run(COMMITTED, "evaluation", RUNS).current() if r["mode"] == mode
    }
    same = [
        all(r[key] == committed[(technique, r["episode"])][key] for key in ("actions", "score", "knocks")) for r in rows
    ]
    decisions = sum(r["steps"] for r in rows)
    ms = round(seconds * 1e3 / decisions, 2)
    return {"technique": technique, "mode": mode, "identical": sum(same), "of": len(rows), "ms_a_decision": ms}


def main(argv: list[str] | None = None) -> list[dict]:
    raw = argparse.RawDescriptionHelpFormatter
    parser = CommandParser(prog="python -m lab.freeway_lockstep_check", description=__doc__, formatter_class=raw)
    parser.add_argument("--technique", choices=TECHNIQUES, default="learned")
    parser.add_argument("--modes", type=int, nargs="+", default=[0, 4])
    parser.add_argument("--out", required=True, help="a folder for the runs played again")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    results = [check(args.technique, mode, args.out) for mode in args.modes]
    print(json.dumps(results))
    return results


if __name__ == "__main__":
    run_command(main, "python -m lab.freeway_lockstep_check")
