"""Where a flow's tasks run: a local thread pool, or a Dask cluster through prefect-dask."""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager

from prefect.task_runners import ThreadPoolTaskRunner

#: Environment variable naming a Dask scheduler (e.g. tcp://10.0.0.5:8786) when --dask-address is not given.
DASK_ADDRESS_ENV = "DYNPLAN_DASK_ADDRESS"


def dask_address(cli_value: str | None = None) -> str | None:
    """The Dask scheduler to use: the command line's, else $DYNPLAN_DASK_ADDRESS, else None (run locally)."""
    return cli_value or os.environ.get(DASK_ADDRESS_ENV) or None


def task_runner(address: str | None, workers: int | None = None):
    """A DaskTaskRunner on `address`, or a local thread pool of `workers` threads (default: one per core)."""
    if address:
        from prefect_dask import DaskTaskRunner

        return DaskTaskRunner(address=address)
    return ThreadPoolTaskRunner(max_workers=workers or os.cpu_count() or 1)


@contextmanager
def dask_scheduler(address: str | None) -> Iterator[None]:
    """Within the block, dask computations run on the cluster at `address` (or on local threads if None)."""
    if not address:
        yield
        return
    from distributed import Client

    with Client(address):
        yield
