"""Prediction error against horizon for any world model, prior checkpoint, caution or context bound, written to the
results' JSON files (`dynplan.evaluation.prediction` measures it): `python -m lab.prediction --model
default [--samples 5] --plot errors.png --figure figure1.png`.
"""

from __future__ import annotations

import json
import os
import shlex
import sys
from pathlib import Path

from dynplan.cli import CommandParser, run_command
from dynplan.env.road import World
from dynplan.evaluation.cases import EVAL_SEED_START
from dynplan.evaluation.prediction import errors_by_horizon, figure1, plot_errors
from dynplan.models.registry import models_of
from dynplan.planning.forward import ForwardModel
from dynplan.world import DEFAULT_WORLD
from lab.context_bound import ContextBoundModel


def world_model(model: str, samples: int = 0, futures: int = 0, prior: str | None = None,
                caution: dict[str, float] | None = None) -> ForwardModel:  # fmt: skip
    """The committed world model of configuration `model`, or its tokenizer with the prior checkpoint `prior`;
    `caution`: what overrides the configuration's own (field → value)."""
    from dynplan.models.registry import caution_for
    from dynplan.models.weights import world_model_paths
    from dynplan.models.world_model import LearnedWorldModel, load_world_model, world_model_parts

    if prior is None:
        return load_world_model(model=model, samples=samples, futures=futures, caution=caution)
    tokenizer, prior_model = world_model_parts((world_model_paths(model)[0], prior), model)
    return LearnedWorldModel(tokenizer, prior_model, samples=samples, futures=futures,
                             caution=caution_for(model, caution))  # fmt: skip


def write_curves(path: str | os.PathLike, curves: dict, command: str) -> None:
    """Add `curves` (name → errors by horizon) to the JSON file at `path`, each with the command that measured it."""
    from dynplan.files import write_bytes_atomic

    try:
        stored = json.loads(Path(path).read_text())
    except FileNotFoundError:
        stored = {"curves": {}}
    for name, curve in curves.items():
        stored["curves"][name] = {**curve, "command": command}
    write_bytes_atomic(path, (json.dumps(stored, indent=1) + "\n").encode())


def main(argv: list[str] | None = None) -> None:
    parser = CommandParser(prog="python -m lab.prediction", description=__doc__)
    parser.add_argument("--model", default="default", choices=models_of(DEFAULT_WORLD))
    parser.add_argument("--samples", type=int, nargs="*", default=[0, 5],
                        help="decoder samples (0: Mid; none given: no such variants)")  # fmt: skip
    parser.add_argument("--futures", type=int, nargs="*", default=[], help="also: code futures sampled from the prior")
    parser.add_argument("--context-bound", type=int, nargs="*", default=[], metavar="N",
                        help="also: the context bound of N frames (each obstacle on the road placed where its "
                        "rounded positions over the last N frames most probably put it), each --occupancy")  # fmt: skip
    parser.add_argument("--prior", help="a prior checkpoint to use instead of the committed one")
    parser.add_argument(
        "--occupancy",
        type=float,
        nargs="+",
        help="obstacle-probability thresholds to compare (0: off; default: the configuration's own)",
    )
    parser.add_argument("--margin", type=int, nargs="+", help="obstacle margins along the lane to compare, in pixels "
                        "(0: off; default: the configuration's own)")  # fmt: skip
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=EVAL_SEED_START,
                        help="seed of the first episode (default: the evaluation's; validation: 2000000)")  # fmt: skip
    parser.add_argument("--plot", help="write the error-against-horizon figure here")
    parser.add_argument("--figure", help="write a Figure-1-style image here")
    parser.add_argument("--out", help="add the curves to this JSON file (curves of the same name are replaced)")
    args = parser.parse_args(argv)
    variants = [(samples, 0) for samples in args.samples] + [(0, futures) for futures in args.futures]
    curves = {}
    cautions = [{name: value for name, value in (("occupancy", occupancy), ("margin", margin)) if value is not None}
                for occupancy in args.occupancy or [None] for margin in args.margin or [None]]  # fmt: skip
    for caution in cautions:
        for samples, futures in variants:
            model = world_model(args.model, samples, futures, args.prior, caution)
            variant = f"{futures} futures" if futures else "mid" if samples == 0 else f"{samples} samples"
            settings = model.caution.recorded().items()
            name = f"{args.model}, {variant}" + "".join(f", {key} {value:g}" for key, value in settings)
            curves[name] = errors_by_horizon(model, args.episodes, first_seed=args.first_seed)
            print(json.dumps({name: curves[name]}))
    for context in args.context_bound:
        for occupancy in sorted(set(args.occupancy or [0.0])):  # the bound has no margin

            def bound(world: World, n: int = context, p: float = occupancy) -> ContextBoundModel:
                return ContextBoundModel(world, n, p)

            name = ContextBoundModel.label(context, occupancy)
            curves[name] = errors_by_horizon(bound, args.episodes, first_seed=args.first_seed)
            print(json.dumps({name: curves[name]}))
    if args.out:
        write_curves(args.out, curves, shlex.join(["python", "-m", "lab.prediction",
                                                   *(sys.argv[1:] if argv is None else argv)]))  # fmt: skip
    if args.plot:
        plot_errors(curves, args.plot)
    if args.figure:
        figure1(world_model(args.model, max(args.samples, default=0), 0, args.prior, cautions[0]), args.figure)


if __name__ == "__main__":
    run_command(main, "python -m lab.prediction")
