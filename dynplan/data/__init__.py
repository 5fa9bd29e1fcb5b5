"""Recorded episodes and the datasets training reads: resumable collection into MCAP logs, the chunked Zarr frames
store (built with dask) and torch datasets over it."""

from dynplan.data.build import build_frame_store_from_logs
from dynplan.data.collect import CollectPlan, log_path, record_episode
from dynplan.data.datasets import FrameDataset, WindowDataset
from dynplan.data.store import fingerprint, list_logs

__all__ = [
    "CollectPlan",
    "FrameDataset",
    "WindowDataset",
    "build_frame_store_from_logs",
    "fingerprint",
    "list_logs",
    "log_path",
    "record_episode",
]
