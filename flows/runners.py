"""Where a flow's tasks run: a local thread pool, or a Dask cluster through prefect-dask."""

from __future__ import annotations

import argparse
import os
import re
import socket
from collections.abc import Iterator
from contextlib import contextmanager

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
    from prefect.task_runners import ThreadPoolTaskRunner

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


def add_dask_option(parser: argparse.ArgumentParser) -> None:
    """The `--dask-address` option."""
    parser.add_argument(
        "--dask-address", help=f"Dask scheduler to run on, tcp://HOST:PORT (default: ${DASK_ADDRESS_ENV}, else local)"
    )


def checked_dask_address(cli_value: str | None = None, timeout_s: float = 5.0) -> str | None:
    """`dask_address(cli_value)`, checked before any work: a ValueError naming the address if it is not
    `[tcp://]HOST:PORT` or nothing answers there within `timeout_s`."""
    if cli_value is not None and not cli_value.strip():
        raise ValueError("--dask-address '': is empty; give tcp://HOST:PORT, or leave the option out to run locally")
    address = dask_address(cli_value)
    if not address:
        return None
    source = "--dask-address" if cli_value else f"${DASK_ADDRESS_ENV}"
    match = re.fullmatch(r"(?:(?:tcp|tls)://)?(\[[^\]]+\]|[^:/\s]+):(\d{1,5})", address)
    if match is None or not 0 < int(match.group(2)) < 65536:
        raise ValueError(f"{source} {address!r}: not a Dask scheduler address; give tcp://HOST:PORT")
    host, port = match.group(1).strip("[]"), int(match.group(2))
    try:
        socket.create_connection((host, port), timeout=timeout_s).close()
    except OSError as error:
        reason = error.strerror or type(error).__name__
        raise ValueError(f"{source} {address}: no Dask scheduler answers there ({reason})") from None
    return address
