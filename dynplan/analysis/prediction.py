"""How a forward model's predictions degrade with the horizon (the paper's Figure 1, quantified).

For held-out episodes (the evaluation seeds, never trained on) and decision points spread along each, the
model predicts 10 frames ahead from the 4 observed; each predicted frame is compared with the truth:
obstacle false negatives and false positives (as fractions of obstacle and free pixels) and the distance
between the predicted and the true goal centres. `python -m dynplan.analysis.prediction --model default
[--samples 5] --plot errors.png --figure figure1.png`.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np

from dynplan.analysis.context_bound import ContextBoundModel
from dynplan.env.config import FREE, GOAL_VALUE, RoadConfig
from dynplan.env.road import World, generate_world, paint
from dynplan.evaluation.cases import EVAL_SEED_START
from dynplan.models.metrics import frame_errors
from dynplan.models.registry import WORLD_MODELS
from dynplan.planning.forward import ForwardModel, goal_centres

HORIZON = 10
#: A missed obstacle pixel with a predicted obstacle this many pixels along its row counts as displaced.
DISPLACED_PX = 2


def foreseeable_frames(world: World, t: int, horizon: int) -> np.ndarray:
    """Frames t+1 … t+horizon (horizon, H, W) as they would be if no obstacle entered the road after decision frame
    t: what a model of frames 0 … t could at best predict (the floor of its misses)."""
    if world.traffic is None or world.layout is None:
        raise ValueError("the floor needs a generated world (its traffic table); this one was read back or built")
    entered = world.traffic.entered_by(world.config.width + t)
    frames = paint(world.config, world.layout, entered, world.goal[: t + 1 + horizon])
    return frames[t + 1 :]


def miss_causes(truth: np.ndarray, predicted: np.ndarray, foreseeable: np.ndarray,
                reach: int = DISPLACED_PX) -> dict[str, float]:  # fmt: skip
    """Each missed obstacle pixel of `predicted` against `truth` (frames (N, H, W)), by cause, as fractions of the
    true obstacle pixels (they sum to the false-negative rate): *unforeseeable* (no obstacle there in the
    `foreseeable` frames: it had not entered the road), *displaced* (a predicted obstacle within `reach` pixels
    along the row) and *lost* (the rest). `floor` is the fraction the foreseeable frames themselves miss."""

    def obstacles(frames: np.ndarray) -> np.ndarray:
        return (frames != FREE) & (frames != GOAL_VALUE)

    true, guess, seen = obstacles(truth), obstacles(predicted), obstacles(foreseeable)
    near = guess.copy()
    for shift in range(1, reach + 1):
        near[..., shift:] |= guess[..., :-shift]
        near[..., :-shift] |= guess[..., shift:]
    missed = true & ~guess
    total = max(int(true.sum()), 1)
    unforeseeable = missed & ~seen
    displaced = missed & seen & near
    return {"floor": float((true & ~seen).sum() / total), "unforeseeable": float(unforeseeable.sum() / total),
            "displaced": float(displaced.sum() / total),
            "lost": float((missed & seen & ~near).sum() / total)}  # fmt: skip


def errors_by_horizon(model: ForwardModel | Callable[[World], ForwardModel], episodes: int = 10, points: int = 10,
                      horizon: int = HORIZON, first_seed: int = EVAL_SEED_START) -> dict:  # fmt: skip
    """Mean false-negative and false-positive rates and goal error (pixels) at each step ahead 1 … horizon, the
    floor of the false negatives (what no model of the past can foresee) and the false negatives by cause
    (`miss_causes`), over `points` decision points of each of `episodes` episodes from seed `first_seed`.
    `model`: a forward model, or what builds one for each episode's world (the context bound)."""
    fn, fp, goal = (np.zeros(horizon) for _ in range(3))
    causes = {cause: np.zeros(horizon) for cause in ("floor", "unforeseeable", "displaced", "lost")}
    goal_counts = np.zeros(horizon)
    n = 0
    for e in range(episodes):
        world = generate_world(RoadConfig(), first_seed + e)
        frames = world.frames
        predictor = model if hasattr(model, "predict") else model(world)
        for t in np.linspace(4, len(frames) - horizon - 1, points).astype(int):
            predicted = predictor.predict(frames[: t + 1], horizon).frames
            truth = frames[t + 1 : t + 1 + horizon]
            foreseeable = foreseeable_frames(world, int(t), horizon)
            for h in range(horizon):
                errors = frame_errors(truth[h : h + 1], predicted[h : h + 1])
                fn[h] += errors["fn_rate"]
                fp[h] += errors["fp_rate"]
                for cause, share in miss_causes(truth[h : h + 1], predicted[h : h + 1], foreseeable[h : h + 1]).items():
                    causes[cause][h] += share
            distance = np.linalg.norm(goal_centres(truth) - goal_centres(predicted), axis=1)
            seen = ~np.isnan(distance)
            goal[seen] += distance[seen]
            goal_counts[seen] += 1
            n += 1
    return {
        "steps_ahead": list(range(1, horizon + 1)),
        "fn_rate": (fn / n).round(5).tolist(),
        "fp_rate": (fp / n).round(5).tolist(),
        "goal_error_px": (goal / np.maximum(goal_counts, 1)).round(3).tolist(),
        "floor_fn_rate": (causes["floor"] / n).round(5).tolist(),
        **{f"fn_{cause}": (causes[cause] / n).round(5).tolist() for cause in ("unforeseeable", "displaced", "lost")},
        "decision_points": n,
        "first_seed": first_seed,
    }


def plot_errors(curves: dict[str, dict], path: str | os.PathLike) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    for name, curve in curves.items():
        for ax, key, title in zip(axes, ("fn_rate", "fp_rate", "goal_error_px"),
                                  ("obstacle false negatives", "obstacle false positives", "goal error (px)"),
                                  strict=True):  # fmt: skip
            ax.plot(curve["steps_ahead"], curve[key], marker="o", label=name)
            ax.set_title(title)
            ax.set_xlabel("steps ahead")
    floors = [curve for curve in curves.values() if "floor_fn_rate" in curve]
    if floors:  # the same episodes for every curve: one floor
        axes[0].plot(floors[0]["steps_ahead"], floors[0]["floor_fn_rate"], "k--", label="floor (not yet on the road)")
    axes[0].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def figure1(model: ForwardModel, path: str | os.PathLike, seed: int = EVAL_SEED_START, t: int = 40,
            steps: tuple[int, ...] = (1, 3, 5, 10)) -> None:  # fmt: skip
    """The paper's Figure 1: per row a step ahead — the oracle frame, the model's, and their error."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from dynplan.render import colorize, error_image

    frames = generate_world(RoadConfig(), seed).frames
    predicted = model.predict(frames[: t + 1], max(steps)).frames
    fig, axes = plt.subplots(len(steps), 3, figsize=(7.5, 2.6 * len(steps)))
    for row, step in enumerate(steps):
        truth, guess = frames[t + step], predicted[step - 1]
        for col, (image, title) in enumerate([(colorize(truth), f"oracle t+{step}"), (colorize(guess), "model"),
                                              (error_image(truth, guess), "error")]):  # fmt: skip
            axes[row, col].imshow(image, interpolation="nearest")
            axes[row, col].set_title(title, fontsize=9)
            axes[row, col].set_axis_off()
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def world_model(model: str, samples: int = 0, futures: int = 0, prior: str | None = None,
                caution: dict[str, float] | None = None, marginal: bool = False,
                temperature: float = 1.0) -> ForwardModel:  # fmt: skip
    """The committed world model of configuration `model`, or its tokenizer with the prior checkpoint `prior`;
    `caution`: what overrides the configuration's own (field → value); `marginal`: the futures merge through their
    mean obstacle probability; `temperature`: the futures' codes are drawn at it."""
    from dynplan.models.registry import caution_for
    from dynplan.models.world_model import LearnedWorldModel, load_world_model, world_model_parts, world_model_paths

    if prior is None:
        return load_world_model(
            model=model, samples=samples, futures=futures, caution=caution, marginal=marginal, temperature=temperature
        )
    tokenizer, prior_model = world_model_parts((world_model_paths(model)[0], prior), model)
    return LearnedWorldModel(tokenizer, prior_model, samples=samples, futures=futures,
                             **caution_for(model, caution).model_dump(), marginal=marginal,
                             temperature=temperature)  # fmt: skip


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
    parser = argparse.ArgumentParser(prog="python -m dynplan.analysis.prediction", description=__doc__)
    parser.add_argument("--model", default="default", choices=list(WORLD_MODELS))
    parser.add_argument("--samples", type=int, nargs="*", default=[0, 5],
                        help="decoder samples (0: Mid; none given: no such variants)")  # fmt: skip
    parser.add_argument("--futures", type=int, nargs="*", default=[], help="also: code futures sampled from the prior")
    parser.add_argument("--marginal", type=int, nargs="*", default=[], help="also: code futures sampled from the "
                        "prior, merged through their mean obstacle probability at the occupancy threshold")  # fmt: skip
    parser.add_argument("--context-bound", type=int, nargs="*", default=[], metavar="N",
                        help="also: the context bound of N frames (each obstacle on the road placed where its "
                        "rounded positions over the last N frames most probably put it), each --occupancy")  # fmt: skip
    parser.add_argument("--temperature", type=float, nargs="+", default=[1.0],
                        help="temperatures the futures' codes are drawn at, to compare (default: 1)")  # fmt: skip
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
    variants = [(samples, 0, False, 1.0) for samples in args.samples]
    sampled = [(futures, False) for futures in args.futures] + [(futures, True) for futures in args.marginal]
    variants += [(0, n, marginal, temperature) for temperature in args.temperature for n, marginal in sampled]
    curves = {}
    cautions = [{name: value for name, value in (("occupancy", occupancy), ("margin", margin)) if value is not None}
                for occupancy in args.occupancy or [None] for margin in args.margin or [None]]  # fmt: skip
    for caution in cautions:
        for samples, futures, marginal, temperature in variants:
            model = world_model(args.model, samples, futures, args.prior, caution, marginal, temperature)
            variant = f"{futures} futures" if futures else "mid" if samples == 0 else f"{samples} samples"
            variant = f"{futures} futures' marginal" if marginal else variant
            variant += f" at temperature {temperature:g}" * (temperature != 1.0)
            settings = (("occupancy", model.occupancy), ("margin", model.margin))
            name = f"{args.model}, {variant}" + "".join(f", {key} {value:g}" for key, value in settings if value)
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
        write_curves(args.out, curves, shlex.join(["python", "-m", "dynplan.analysis.prediction",
                                                   *(sys.argv[1:] if argv is None else argv)]))  # fmt: skip
    if args.plot:
        plot_errors(curves, args.plot)
    if args.figure:
        figure1(world_model(args.model, max(args.samples, default=0), 0, args.prior, cautions[0]), args.figure)


if __name__ == "__main__":
    main()
