"""`python -m flows.replay log.mcap`: run a planner against a recorded episode.

Prints the outcome (goal / timeout / death), the steps and the time per decision; writes a replay MCAP
(world, the agent's pose, actions and view, the planner's imagined frames) and optionally a GIF.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from prefect import flow

from dynplan.config import ConfigError
from dynplan.evaluation.replay import default_outputs, planners, prepare, replay
from dynplan.evaluation.techniques import TECHNIQUES
from dynplan.files import check_output
from dynplan.logs.reader import LogError
from dynplan.models.registry import WORLD_MODELS
from flows.cli import add_debug_option, run


@flow(name="replay-episode", log_prints=True)
def replay_episode(
    log: str,
    planner: str = "oracle",
    agent_speed: float = 1.0,
    rollout_steps: int = 3,
    playouts: int = 100,
    out: str | None = None,
    gif: str | None = None,
    seed: int = 0,
    model: str = "default",
    samples: int = 0,
    futures: int = 0,
    model_dir: str | None = None,
) -> dict:
    """Replay one recorded episode through a planner."""
    result = replay(log, planner, agent_speed, rollout_steps, playouts, out, gif, seed, model, samples, futures,
                    model_dir)  # fmt: skip
    result = result.to_dict()
    print(f"{result['outcome']} after {result['steps']} steps; decision {result['decision_ms_median']:.3f} ms "
          f"(median), {result['decision_ms_mean']:.3f} ms (mean); replay log: {result['out']}")  # fmt: skip
    return result


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(prog="python -m flows.replay", description=__doc__)
    parser.add_argument("log", help="episode log (.mcap) from flows.collect")
    parser.add_argument(
        "--planner",
        default="oracle",
        choices=planners(),
        help="a technique ("
        + ", ".join(f"{n}: {t.description}" for n, t in TECHNIQUES.items())
        + "), or model: the learned model with --samples and --futures (default oracle)",
    )
    parser.add_argument("--model", default="default", choices=list(WORLD_MODELS), help="learned model configuration")
    parser.add_argument("--samples", type=int, default=0, help="decoder samples merged by the learned model (0: Mid)")
    parser.add_argument("--futures", type=int, default=0, help="code futures sampled from the prior and merged")
    parser.add_argument("--agent-speed", type=float, default=1.0, help="1.0 (the paper's 2×) or 0.5 (1×)")
    parser.add_argument("--rollout-steps", type=int, default=3, help="search horizon k (default 3)")
    parser.add_argument("--playouts", type=int, default=100, help="MCTS playouts per decision (default 100)")
    parser.add_argument(
        "--out", help="replay MCAP to write (default: ../replays/EPISODE.replay-PLANNER.mcap from the log)"
    )
    parser.add_argument("--gif", help="also write a GIF: observed | true future | predicted | error")
    parser.add_argument("--model-dir", help="learned weights under MODEL_DIR/<model>/{vqvae,pixelcnn}.pt "
                        "(default: the committed ones)")  # fmt: skip
    parser.add_argument("--seed", type=int, default=0, help="seed of the planner's own randomness (>= 0)")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    add_debug_option(parser)
    args = parser.parse_args(argv)
    out = args.out or str(default_outputs(args.log, args.planner, args.model, args.samples, args.futures))
    try:  # fail fast, with one line, before any flow machinery starts
        if not 0 <= args.seed < 2**32:
            raise ValueError(f"--seed={args.seed} is invalid; valid range [0, 2**32)")
        check_output(out, "--out", "file", inputs=(args.log,))
        if args.gif:
            if Path(args.gif).resolve() == Path(out).resolve():
                raise ValueError(f"--gif {args.gif}: is the path of --out too; give the GIF a path of its own")
            check_output(args.gif, "--gif", "file", inputs=(args.log,))
        prepare(args.log, args.planner, args.agent_speed, args.rollout_steps, args.playouts, args.model, args.samples,
                args.futures, args.model_dir)  # fmt: skip
    except (LogError, ConfigError, ValueError) as error:
        print(f"error: {error}", file=sys.stderr)
        raise SystemExit(2) from None
    result = replay_episode(args.log, args.planner, args.agent_speed, args.rollout_steps, args.playouts, out,
                            args.gif, args.seed, args.model, args.samples, args.futures, args.model_dir)  # fmt: skip
    if args.json:
        print(json.dumps(result))
    return result


if __name__ == "__main__":
    run(main, "python -m flows.replay")
