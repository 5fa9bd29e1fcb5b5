"""Recorded data: collecting episode logs, the chunked Zarr frame store, and torch datasets over it."""
