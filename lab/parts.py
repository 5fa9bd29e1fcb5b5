"""Which part of a learned prediction costs an agent its goals: its obstacles or its goal.

An evaluated case replays exactly (recorded world, planner seed, the model's draws), so the same cases can be
played again with the prediction's parts swapped for the truth's, each planner seeded as the evaluation seeds
it. Views, each planned with over the same episodes:

- `learned`: the prediction as the planner sees it (the row itself, replayed: a check of the replay);
- `true_goal`: the learned obstacles (caution included), with the true goal drawn under them;
- `true_obstacles`: the true obstacles, with the learned goal drawn under them;
- `truth`: both parts true, the oracle's frames under this technique's planner seeds (the control: the oracle's
  own row has other seeds).

`python -m lab.parts --technique samples5 --agent-speed 0.5 --rollout-steps 3 5 --first-seed 2000000
--out FILE.json`
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from collections import Counter
from collections.abc import Sequence

import numpy as np

from dynplan.cli import CommandParser, run_command
from dynplan.env.config import FREE, GOAL_VALUE, RoadConfig
from dynplan.env.road import generate_world
from dynplan.evaluation.agent import AgentSpec
from dynplan.evaluation.cases import EVAL_SEED_START, Case
from dynplan.evaluation.protocol import case_agent
from dynplan.evaluation.techniques import TECHNIQUES
from dynplan.files import write_bytes_atomic
from dynplan.models.caution import Caution
from dynplan.models.registry import models_of
from dynplan.planning.episode import run_episodes
from dynplan.planning.forward import Prediction
from dynplan.world import DEFAULT_WORLD

VIEWS = ("learned", "true_goal", "true_obstacles", "truth")
#: Episodes played in one lockstep batch.
BATCH = 50


def swap_parts(learned: np.ndarray, truth: np.ndarray, view: str) -> np.ndarray:
    """The frames (k, H, W) uint8 of `view` (one of `VIEWS`) from a learned prediction's frames and the true
    frames of the same steps: one part from each, the goal under the obstacles as everywhere else."""
    if view not in VIEWS:
        raise ValueError(f"view must be one of {VIEWS}, got {view!r}")
    if view == "learned":
        return learned
    if view == "truth":
        return truth
    obstacles, goal = (learned, truth) if view == "true_goal" else (truth, learned)
    road = np.where(obstacles == GOAL_VALUE, FREE, obstacles)
    return np.where((road == FREE) & (goal == GOAL_VALUE), GOAL_VALUE, road).astype(np.uint8)


class SwappedModel:
    """A learned forward model with one part of its prediction swapped for the recorded world's (`swap_parts`);
    it batches as the learned model does."""

    def __init__(self, learned, frames: np.ndarray, view: str):
        swap_parts(frames[:1], frames[:1], view)  # the view's name checked once
        self.learned, self.frames, self.view = learned, frames, view
        self.name = f"{learned.name}, {view}"
        self.batch_key = learned.batch_key

    def cost(self, k: int) -> int:
        return self.learned.cost(k)

    @staticmethod
    def predict_batch(models: Sequence[SwappedModel], observed: Sequence[np.ndarray],
                      ks: Sequence[int]) -> list[Prediction]:  # fmt: skip
        learned = type(models[0].learned).predict_batch([m.learned for m in models], observed, ks)
        out = []
        for model, seen, prediction in zip(models, observed, learned, strict=True):
            t = len(seen) - 1
            truth = model.frames[t + 1 : t + 1 + len(prediction.frames)]
            out.append(Prediction.from_frames(swap_parts(prediction.frames[: len(truth)], truth, model.view)))
        return out

    def predict(self, observed: np.ndarray, k: int) -> Prediction:
        return SwappedModel.predict_batch([self], [observed], [k])[0]


def play_views(technique: str, model: str, agent_speed: float, rollout_steps: int, seeds: Sequence[int],
               views: Sequence[str] = VIEWS, spec: AgentSpec | None = None) -> dict[str, dict[int, str]]:  # fmt: skip
    """Each view's outcome ("goal" | "timeout" | "death") per episode seed, the planners seeded as the
    evaluation's case of `technique` seeds them; `spec`: the agents' settings (playouts, caution overrides, other
    weights as `flows.evaluate --model-dir`)."""
    from dynplan.progress import progress

    out: dict[str, dict[int, str]] = {}
    config = RoadConfig(agent_speed=agent_speed)
    worlds = [generate_world(config, seed) for seed in seeds]
    for view in views:
        planners, models = [], []
        for world in worlds:
            case = Case(technique, agent_speed, rollout_steps, int(world.seed), model)
            planner, learned = case_agent(case, world, spec)
            planners.append(planner)
            models.append(SwappedModel(learned, world.frames, view))
        outcomes: dict[int, str] = {}
        starts = range(0, len(worlds), BATCH)
        for start in progress(starts, total=len(starts), description=f"{view}, k = {rollout_steps}"):
            stop = start + BATCH
            results = run_episodes(worlds[start:stop], planners[start:stop], models[start:stop], agent_speed,
                                   rollout_steps)  # fmt: skip
            outcomes.update({int(w.seed): r.outcome for w, r in zip(worlds[start:stop], results, strict=True)})
        out[view] = outcomes
    return out


def main(argv: list[str] | None = None) -> dict:
    parser = CommandParser(prog="python -m lab.parts", description=__doc__,
                           formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    parser.add_argument("--technique", default="samples5",
                        choices=[n for n, t in TECHNIQUES.items() if t.world_model and t.search])  # fmt: skip
    parser.add_argument("--model", default="default", choices=models_of(DEFAULT_WORLD))
    parser.add_argument("--agent-speed", type=float, default=0.5)
    parser.add_argument("--rollout-steps", type=int, nargs="+", default=[3])
    parser.add_argument("--model-dir", help="learned world models under MODEL_DIR/<model>/{vqvae,pixelcnn}.pt "
                        "(default: the committed weights)")  # fmt: skip
    parser.add_argument("--views", nargs="+", default=list(VIEWS[:3]), choices=VIEWS,
                        help="views to play (default: the three with a learned part; truth: the control)")  # fmt: skip
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--first-seed", type=int, default=EVAL_SEED_START,
                        help="seed of the first episode (default: the evaluation's; validation: 2000000)")  # fmt: skip
    for name, info in Caution.model_fields.items():
        parser.add_argument(f"--{name}", type=info.annotation, help=f"caution override: {info.description}")
    parser.add_argument("--out", help="write the outcomes and their counts here (JSON)")
    args = parser.parse_args(argv)
    caution = {name: value for name in Caution.model_fields if (value := getattr(args, name)) is not None}
    seeds = range(args.first_seed, args.first_seed + args.episodes)
    rows = []
    for k in args.rollout_steps:
        spec = AgentSpec(model_dir=args.model_dir, caution=caution)
        played = play_views(args.technique, args.model, args.agent_speed, k, seeds, args.views, spec)
        for view, outcomes in played.items():
            counts = Counter(outcomes.values())
            rows.append({"k": k, "view": view, **{o: counts[o] for o in ("goal", "timeout", "death")},
                         "outcomes": {str(s): o for s, o in outcomes.items()}})  # fmt: skip
            print(f"k = {k}, {view}: {counts['goal']} / {counts['timeout']} / {counts['death']} (G / T / D)")
    if args.out:
        payload = {"technique": args.technique, "model": args.model, "agent_speed": args.agent_speed,
                   "caution": caution, "model_dir": args.model_dir, "first_seed": args.first_seed,
                   "episodes": args.episodes, "rows": rows,
                   "command": shlex.join(["python", "-m", "lab.parts",
                                          *(sys.argv[1:] if argv is None else argv)])}  # fmt: skip
        write_bytes_atomic(args.out, (json.dumps(payload, indent=1) + "\n").encode())
    return {"rows": rows}


if __name__ == "__main__":
    run_command(main, "python -m lab.parts")
