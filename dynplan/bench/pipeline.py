"""`pipeline`: the collect-train-eval `quick` preset's wall time per stage, and the evaluation's speed-up on a
Dask cluster of two single-thread workers against one — measured by `python -m flows.bench_pipeline`, run here
as a command (the library imports no flows).
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path


def bench_pipeline(quick: bool = True) -> dict[str, dict[str, float]]:
    """Run the flows' benchmark in a child process and return its figures."""
    with tempfile.TemporaryDirectory(prefix="dynplan-bench-") as tmp:
        out = Path(tmp) / "pipeline.json"
        argv = [sys.executable, "-m", "flows.bench_pipeline", "--out", str(out), *([] if quick else ["--no-quick"])]
        done = subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        if done.returncode != 0:
            raise RuntimeError(f"python -m flows.bench_pipeline failed (exit {done.returncode}): {done.stderr[-2000:]}")
        return json.loads(out.read_text())
