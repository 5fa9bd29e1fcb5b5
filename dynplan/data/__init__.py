"""Recorded episodes and the datasets training reads: resumable collection into MCAP logs, the chunked Zarr frames
store (built with dask) and torch datasets over it.

Each public name is imported from its module when first used, so that `dynplan.data.collect` (what recording and a
command's `--help` need) loads neither torch nor dask.
"""

from dynplan.lazy import lazy_names

#: Each public name by its module, imported when first used (`dynplan.lazy`).
_PUBLIC = {
    "CollectPlan": "dynplan.data.collect",
    "FrameDataset": "dynplan.data.datasets",
    "WindowDataset": "dynplan.data.datasets",
    "build_frame_store_from_logs": "dynplan.data.build",
    "fingerprint": "dynplan.data.store",
    "list_logs": "dynplan.data.store",
    "log_path": "dynplan.data.collect",
    "record_episode": "dynplan.data.collect",
}
__getattr__, __dir__ = lazy_names(__name__, _PUBLIC)
__all__ = sorted(_PUBLIC)
