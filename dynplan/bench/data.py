"""`data`: episodes logged per second, frames converted to Zarr per second, bytes per frame in MCAP and Zarr."""

from __future__ import annotations

import os
import statistics
import tempfile
import time
from pathlib import Path

from dynplan.data.build import build_frame_store_from_logs
from dynplan.data.collect import record_episode
from dynplan.data.store import list_logs


def _folder_bytes(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())


def bench_data(episodes: int = 20, repeats: int = 3) -> dict[str, dict[str, float]]:
    """Record `episodes` 407-frame logs and convert them, `repeats` times; medians of each stage."""
    log_rates, frame_rates, mcap_bpf, zarr_bpf = [], [], [], []
    for _ in range(repeats):
        with tempfile.TemporaryDirectory() as tmp:
            logs, store = Path(tmp) / "logs", Path(tmp) / "frames.zarr"
            start = time.perf_counter()
            for seed in range(episodes):
                record_episode(logs, seed)
            log_rates.append(episodes / (time.perf_counter() - start))
            paths = list_logs(logs)
            start = time.perf_counter()
            report = build_frame_store_from_logs(store, paths)
            n_frames = report.episodes * 407
            frame_rates.append(n_frames / (time.perf_counter() - start))
            mcap_bpf.append(_folder_bytes(logs) / n_frames)
            zarr_bpf.append(_folder_bytes(store / "frames") / n_frames)
    return {
        "collect": {"episodes_per_s": round(statistics.median(log_rates), 1), "cores": os.cpu_count() or 1},
        "build": {"frames_per_s": round(statistics.median(frame_rates))},
        "size": {
            "mcap_bytes_per_frame": round(statistics.median(mcap_bpf), 1),
            "zarr_bytes_per_frame": round(statistics.median(zarr_bpf), 1),
            "raw_bytes_per_frame": 48 * 48,
        },
    }
