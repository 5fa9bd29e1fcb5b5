"""How a forward model's predictions degrade with the horizon (the paper's Figure 1, quantified), as the pipeline's
report draws it.

For held-out episodes (the evaluation seeds, never trained on) and decision points spread along each, the
model predicts 10 frames ahead from the observed frames; each predicted frame is compared with the truth:
obstacle false negatives and false positives (as fractions of obstacle and free pixels) and the distance
between the predicted and the true goal centres; each miss is classified by cause (`miss_causes`).
"""

from __future__ import annotations

import os
from collections.abc import Callable

import numpy as np

from dynplan.env.config import FREE, GOAL_VALUE, RoadConfig
from dynplan.env.road import World, generate_world, paint
from dynplan.evaluation.cases import EVAL_SEED_START
from dynplan.models.metrics import frame_errors
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


def miss_causes(
    truth: np.ndarray, predicted: np.ndarray, foreseeable: np.ndarray, reach: int = DISPLACED_PX
) -> dict[str, float]:
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
    return {
        "floor": float((true & ~seen).sum() / total),
        "unforeseeable": float(unforeseeable.sum() / total),
        "displaced": float(displaced.sum() / total),
        "lost": float((missed & seen & ~near).sum() / total),
    }


def errors_by_horizon(
    model: ForwardModel | Callable[[World], ForwardModel],
    episodes: int = 10,
    points: int = 10,
    horizon: int = HORIZON,
    first_seed: int = EVAL_SEED_START,
) -> dict:
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
        for ax, key, title in zip(
            axes,
            ("fn_rate", "fp_rate", "goal_error_px"),
            ("obstacle false negatives", "obstacle false positives", "goal error (px)"),
            strict=True,
        ):
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


def figure1(
    model: ForwardModel,
    path: str | os.PathLike,
    seed: int = EVAL_SEED_START,
    t: int = 40,
    steps: tuple[int, ...] = (1, 3, 5, 10),
) -> None:
    """The paper's Figure 1: per row a step ahead — the oracle frame, the model's, and their error."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from dynplan.env.colors import colorize
    from dynplan.render import error_image

    frames = generate_world(RoadConfig(), seed).frames
    predicted = model.predict(frames[: t + 1], max(steps)).frames
    fig, axes = plt.subplots(len(steps), 3, figsize=(7.5, 2.6 * len(steps)))
    for row, step in enumerate(steps):
        truth, guess = frames[t + step], predicted[step - 1]
        for col, (image, title) in enumerate(
            [(colorize(truth), f"oracle t+{step}"), (colorize(guess), "model"), (error_image(truth, guess), "error")]
        ):
            axes[row, col].imshow(image, interpolation="nearest")
            axes[row, col].set_title(title, fontsize=9)
            axes[row, col].set_axis_off()
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
