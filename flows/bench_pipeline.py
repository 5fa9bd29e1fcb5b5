"""`python -m flows.bench_pipeline --out FILE`, what `python -m dynplan.bench pipeline` runs: the
collect-train-eval `quick` preset's wall time per stage, and the evaluation's speed-up on a Dask cluster of two
single-thread workers against one (each a local process, through prefect-dask).

The evaluation case is compute-bound on purpose — 1× agent, k = 10, 1,000 playouts per decision, oracle model —
so that the ratio measures the cluster rather than Prefect's per-task overhead.
"""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

EVAL = {"techniques": ["oracle"], "agent_speeds": [0.5], "rollout_steps": [10], "episodes": 12}
PLAYOUTS = 1000


def _evaluate_on_cluster(workers: int, log_dir: Path, results_dir: Path) -> float:
    from distributed import LocalCluster
    from prefect_dask import DaskTaskRunner

    from dynplan.evaluation.agent import AgentSpec
    from dynplan.evaluation.cases import CasePlan
    from dynplan.worlds.road.evaluate import RoadEvaluation
    from flows.worlds import evaluate_world

    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        runner = DaskTaskRunner(address=cluster.scheduler_address)
        start = time.perf_counter()
        agent = AgentSpec(playouts=PLAYOUTS)
        request = RoadEvaluation(plan=CasePlan(**EVAL), agent=agent, log_dir=str(log_dir), results_dir=str(results_dir))
        evaluate_world.with_options(task_runner=runner)("road", request.model_dump(mode="json"), "bench_pipeline")
        return time.perf_counter() - start


def bench_pipeline(quick: bool = True) -> dict[str, dict[str, float]]:
    """Run the quick preset in a temporary folder (stage times from its report), then the evaluation on 1 and
    2 Dask workers (fresh results each, the same recorded episodes)."""
    from prefect.testing.utilities import prefect_test_harness

    from flows.collect import collect_episodes
    from flows.collect_train_eval import collect_train_eval

    results: dict[str, dict[str, float]] = {}
    with tempfile.TemporaryDirectory(prefix="dynplan-bench-") as tmp, prefect_test_harness(server_startup_timeout=120):
        root = Path(tmp)
        if quick:
            start = time.perf_counter()
            report = Path(collect_train_eval(preset="quick", out=str(root)))
            total = time.perf_counter() - start
            stages = json.loads((report.parent / "stages.json").read_text())
            results["quick_preset"] = {s["name"]: round(s["wall_s"], 1) for s in stages} | {"total_s": round(total, 1)}
        logs = root / "eval_logs"
        collect_episodes(out=str(logs), episodes=EVAL["episodes"], seed=1_000_000)
        one = _evaluate_on_cluster(1, logs, root / "results1")
        two = _evaluate_on_cluster(2, logs, root / "results2")
        results["evaluation_dask"] = {
            "episodes": EVAL["episodes"],
            "one_worker_s": round(one, 1),
            "two_workers_s": round(two, 1),
            "speedup": round(one / two, 2),
        }
    return results


def main(argv: list[str] | None = None) -> dict[str, dict[str, float]]:
    from dynplan.cli import CommandParser
    from dynplan.files import write_bytes_atomic
    from dynplan.paths import PathArgument, PathKind

    parser = CommandParser(prog="python -m flows.bench_pipeline", description=__doc__)
    parser.add_argument(
        "--out", type=PathArgument(PathKind.OUTPUT_FILE), required=True, help="where to write the figures (JSON)"
    )
    parser.add_argument("--no-quick", action="store_true", help="time the Dask evaluation only")
    args = parser.parse_args(argv)
    results = bench_pipeline(quick=not args.no_quick)
    write_bytes_atomic(args.out, json.dumps(results).encode())
    return results


if __name__ == "__main__":
    from dynplan.cli import run_command

    run_command(main, "python -m flows.bench_pipeline")
