"""`startup`: how long a newcomer waits for a command to answer — `import dynplan`, each flow's `--help` and a usage
error, `flows.play` without a display, collecting an episode already recorded — as the median wall time of
`repeats` fresh processes (run as commands: the library imports no flows), with the 1-minute load average before
and after, so a reader knows whether the machine was idle.
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import time

from dynplan.world import DEFAULT_WORLD, world_names

#: Each case: the arguments after `python`, and the answer's exit status (0 for help, 2 for a usage error).
CASES: dict[str, tuple[tuple[str, ...], int]] = {
    "import dynplan": (("-c", "import dynplan"), 0),
    "flows.collect --help": (("-m", "flows.collect", "--help"), 0),
    "flows.collect usage error": (("-m", "flows.collect", "--episodes", "0"), 2),
    "flows.evaluate --help": (("-m", "flows.evaluate", "--help"), 0),
    "flows.evaluate usage error": (("-m", "flows.evaluate", "--episodes", "0"), 2),
    "flows.build_datasets --help": (("-m", "flows.build_datasets", "--help"), 0),
    "flows.build_datasets usage error": (("-m", "flows.build_datasets", "--bogus"), 2),
    "flows.train --help": (("-m", "flows.train", "--help"), 0),
    "flows.train usage error": (("-m", "flows.train", "nosuchstage"), 2),
    "flows.collect_train_eval --help": (("-m", "flows.collect_train_eval", "--help"), 0),
    "flows.collect_train_eval usage error": (("-m", "flows.collect_train_eval", "--preset", "nosuch"), 2),
    "flows.replay --help": (("-m", "flows.replay", "--help"), 0),
    "flows.replay usage error": (("-m", "flows.replay"), 2),
    "flows.view usage error": (("-m", "flows.view"), 2),
    "flows.play without a display": (("-m", "flows.play"), 2),
}
#: Every other world's `flows.evaluate --help` (each world's command half loads on its own).
CASES |= {
    f"flows.evaluate --world {name} --help": (("-m", "flows.evaluate", "--world", name, "--help"), 0)
    for name in world_names()
    if name != DEFAULT_WORLD
}
#: The environment of every case: no display (so `flows.play` answers that it has none rather than opening one).
HEADLESS = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
#: The most seconds a case may take (the newcomer's budget), and collecting an episode that is already there.
TARGET_S, EXISTING_TARGET_S = 0.5, 3.0


def _seconds(args: tuple[str, ...], status: int) -> float:
    start = time.perf_counter()
    done = subprocess.run(
        [sys.executable, *args], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=HEADLESS
    )
    seconds = time.perf_counter() - start
    if done.returncode != status:
        raise RuntimeError(f"python {' '.join(args)} exited {done.returncode}, not {status}: {done.stderr[-500:]}")
    return seconds


def bench_startup(repeats: int = 5) -> dict[str, dict[str, float]]:
    """Median seconds of each case over `repeats` runs (after one warm-up run, so the file cache is warm), and
    whether it is within `TARGET_S`."""
    load_before = os.getloadavg()[0]
    results: dict[str, dict[str, float]] = {}
    for case, (args, status) in CASES.items():
        _seconds(args, status)
        median = statistics.median(_seconds(args, status) for _ in range(repeats))
        results[case] = {"median_s": round(median, 3), "within_0.5_s": float(median <= TARGET_S)}
    with tempfile.TemporaryDirectory(prefix="dynplan-bench-") as out:
        args = ("-m", "flows.collect", "--episodes", "1", "--seed", "1000000", "--out", out)
        _seconds(args, 0)  # records it
        median = statistics.median(_seconds(args, 0) for _ in range(repeats))
        results["flows.collect of an episode already recorded"] = {
            "median_s": round(median, 3),
            "within_3_s": float(median <= EXISTING_TARGET_S),
        }
    results["machine"] = {
        "cores": float(os.cpu_count() or 1),
        "load_1min_before": round(load_before, 2),
        "load_1min_after": round(os.getloadavg()[0], 2),
    }
    return results
