"""Whether the default prior trains faster in another memory layout or compiled: `python -m lab.training_layouts
[--steps 4] [--rounds 5] [--threads 2]`.

Random code windows at the default prior's batch, Adam steps as `dynplan.training.pixelcnn` takes them: eager
float32 as trained today, the model and its activations in channels-last layout, and `torch.compile` (inductor,
its compile time reported apart); rounds alternated in one process, windows/s medians and ratios to eager.
"""

from __future__ import annotations

import json
import statistics
import time

import torch

from dynplan.bench.prior import rows_loss, train_rate
from dynplan.cli import CommandParser, run_command
from dynplan.models.pixelcnn import ConditionalPixelCNN
from dynplan.models.registry import world_model_spec


def _variants(name: str) -> tuple[dict, torch.Tensor, torch.Tensor]:
    """(variant → (model, optimiser, loss function)), a context batch and a target batch of preset `name`."""
    spec = world_model_spec(name)
    config, (h, w) = spec.prior, spec.tokenizer.grid
    context = torch.randint(0, config.codebook_size, (config.batch_size, config.context, h, w))
    target = torch.randint(0, config.codebook_size, (config.batch_size, h, w))
    variants = {}
    for variant in ("eager", "channels_last", "compiled"):
        torch.manual_seed(0)
        model = ConditionalPixelCNN(config).train()
        if variant == "channels_last":
            model = model.to(memory_format=torch.channels_last)
        optimiser = torch.optim.Adam(model.parameters(), lr=config.learning_rate)
        loss = rows_loss
        if variant == "compiled":
            compiled = torch.compile(model)

            def loss(_, c, t, compiled=compiled):
                return compiled(c, t).loss

        variants[variant] = (model, optimiser, loss)
    return variants, context, target


def compare(name: str, steps: int, rounds: int) -> dict:
    variants, context, target = _variants(name)
    result: dict = {"preset": name, "batch": len(target), "threads": torch.get_num_threads()}
    for variant, (model, optimiser, loss) in variants.items():  # warm-up; the compiled one compiles here
        start = time.perf_counter()
        train_rate(model, loss, optimiser, context, target, 1)
        result[f"{variant}_first_step_s"] = round(time.perf_counter() - start, 1)
    rates: dict[str, list[float]] = {variant: [] for variant in variants}
    for _ in range(rounds):
        for variant, (model, optimiser, loss) in variants.items():
            rates[variant].append(train_rate(model, loss, optimiser, context, target, steps))
    eager = statistics.median(rates["eager"])
    for variant, values in rates.items():
        result[f"{variant}_windows_per_s"] = round(statistics.median(values), 1)
        result[f"{variant}_ratio"] = round(statistics.median(values) / eager, 3)
    return result


def main(argv: list[str] | None = None) -> None:
    parser = CommandParser(prog="python -m lab.training_layouts", description=__doc__)
    parser.add_argument("--steps", type=int, default=4)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--preset", default="default")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    print(json.dumps(compare(args.preset, args.steps, args.rounds)))


if __name__ == "__main__":
    run_command(main, "python -m lab.training_layouts")
