"""`python -m flows.demo`: play one demonstration episode and write its GIF."""

from __future__ import annotations

import argparse
import json

from prefect import flow

from dynplan.demo import run_demo


@flow(name="demo-episode", log_prints=True)
def demo_episode(out: str = "datasets/demo", seed: int = 0, agent_speed: float = 1.0, level: int = 6) -> dict:
    """Play one episode of `dynplan/Road-v0` with the greedy lookahead agent; write a GIF under `out`."""
    result = run_demo(out, seed=seed, agent_speed=agent_speed, level=level).to_dict()
    print(f"episode seed={seed}: {result['outcome']} after {result['steps']} steps; GIF: {result['gif']}")
    return result


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(prog="python -m flows.demo", description=__doc__)
    parser.add_argument("--out", default="datasets/demo", help="output folder (default: datasets/demo)")
    parser.add_argument("--seed", type=int, default=0, help="episode seed (default: 0)")
    parser.add_argument("--agent-speed", type=float, default=1.0, help="pixels per step: 1.0 (2×) or 0.5 (1×)")
    parser.add_argument("--level", type=int, default=6, help="traffic level (default: 6)")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    args = parser.parse_args(argv)
    result = demo_episode(out=args.out, seed=args.seed, agent_speed=args.agent_speed, level=args.level)
    if args.json:
        print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
