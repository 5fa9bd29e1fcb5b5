"""How dynplan writes and reads its Zarr arrays: checksummed chunks, appends no reader sees until they are whole,
and reads that name the damaged chunk.

Every chunk is zstd-compressed and then carries a CRC-32C of its compressed bytes (Zarr v3's `crc32c` codec), so
a flipped byte is an error on read, in any Zarr reader, instead of wrong pixels. Every chunk is written, even one
that holds only the fill value (which Zarr would leave out), so a missing chunk file is always damage, never a chunk of
zeros: `read` refuses it rather than return fill values. Rows are appended by writing them
through a view with the larger shape, which is never saved, and only then resizing the array: a reader that
knows nothing of dynplan sees the old shape, with complete rows, until the new rows are all written.
"""

from __future__ import annotations

import itertools
import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import zarr
from zarr.codecs import Crc32cCodec, ZstdCodec

from dynplan.cli import InputError
from dynplan.data.contents import Check

#: Bytes-to-bytes codecs of every array dynplan writes: compression, then the checksum of what is stored.
COMPRESSORS = (ZstdCodec(level=3), Crc32cCodec())


class ChunkError(InputError):
    """A chunk of a store could not be read (checksum mismatch, undecodable or missing); the message names the
    store, the array, the chunk and the episodes it holds."""


def is_checksummed(array: zarr.Array) -> bool:
    """Whether the array's chunks carry a checksum."""
    return any(isinstance(codec, Crc32cCodec) for codec in array.metadata.codecs)


def staged(array: zarr.Array, rows: int) -> zarr.Array:
    """A view of `array` with `rows` rows along its first axis whose shape is never saved: what is written through
    it is invisible to every reader until `array.resize` commits the new shape."""
    metadata = array.metadata.update_shape((rows, *array.shape[1:]))
    return zarr.Array(zarr.AsyncArray(metadata=metadata, store_path=array.store_path, config=WRITE_EVERY_CHUNK))


#: How dynplan writes: every chunk, one of fill values too (a missing chunk is then damage).
WRITE_EVERY_CHUNK = {"write_empty_chunks": True}


def writable(array: zarr.Array) -> zarr.Array:
    """`array`, writing every chunk it is given (`WRITE_EVERY_CHUNK`)."""
    return array.with_config(WRITE_EVERY_CHUNK)


@dataclass(frozen=True)
class Chunk:
    """One chunk of an array: its key (e.g. 'c/12/0/0/0'), its region and the rows (episodes) it covers."""

    array: str
    key: str
    region: tuple[slice, ...]

    @property
    def rows(self) -> range:
        return range(self.region[0].start, self.region[0].stop)


def chunks(array: zarr.Array, rows: int | None = None, start: int = 0) -> Iterator[Chunk]:
    """The chunks of `array` that hold any of its rows `start` … `rows` − 1 (default: all of its rows)."""
    rows = array.shape[0] if rows is None else min(rows, array.shape[0])
    shape = (rows, *array.shape[1:])
    ranges = [range(0, -(-size // step)) for size, step in zip(shape, array.chunks, strict=True)]
    ranges[0] = range(min(start // array.chunks[0], ranges[0].stop), ranges[0].stop)
    for coords in itertools.product(*ranges):
        region = tuple(
            slice(c * step, min(size, (c + 1) * step))
            for c, step, size in zip(coords, array.chunks, shape, strict=True)
        )
        yield Chunk(array.basename, array.metadata.encode_chunk_key(coords), region)


def chunk_file(store: str | os.PathLike, array: zarr.Array, key: str) -> Path:
    """Where a chunk of a local store lives."""
    return Path(store, array.path, key)


def chunk_problem(store: str | os.PathLike, array: zarr.Array, chunk: Chunk, check: Check | None = None) -> str | None:
    """Why `chunk` cannot be read, or (`check`) what it holds cannot be trusted (None: it reads). A missing chunk is a
    problem too: Zarr would return its fill value for it without a word."""
    if not chunk_file(store, array, chunk.key).is_file():
        return "the chunk file is missing"
    try:
        values = array[chunk.region]
    except (ValueError, RuntimeError) as error:  # crc32c: ValueError; zstd: RuntimeError
        return "its CRC-32C does not match its bytes" if "checksum do not match" in str(error) else str(error)
    return check(values, chunk.rows.start) if check else None


def check_present(
    store: str | os.PathLike, array: zarr.Array, rows: range, describe: Callable[[range], str] | None = None
) -> None:
    """A ChunkError naming the first chunk holding any of `rows` whose file is missing (Zarr would read its fill
    values without a word)."""
    for chunk in chunks(array, rows.stop, start=rows.start):
        if not chunk_file(store, array, chunk.key).is_file():
            raise damaged(store, array, chunk, "the chunk file is missing", describe)


def read(
    store: str | os.PathLike,
    array: zarr.Array,
    selection,
    describe: Callable[[range], str] | None = None,
    check: Check | None = None,
):
    """`array[selection]`, or a ChunkError naming the store, the array, the damaged (or missing) chunk and (through
    `describe(rows)`) the episodes in it; with `check`, also where what it holds cannot be trusted. `selection` is
    an int or a slice along the first axis."""
    first = selection if isinstance(selection, int) else (selection.start or 0)
    last = first + 1 if isinstance(selection, int) else (selection.stop or array.shape[0])
    check_present(store, array, range(first, last), describe)
    touched = list(chunks(array, last, start=first))
    try:
        values = array[selection]
    except (ValueError, RuntimeError) as error:
        for chunk in touched:
            problem = chunk_problem(store, array, chunk)
            if problem:
                raise damaged(store, array, chunk, problem, describe) from error
        raise
    problem = check(values[None] if isinstance(selection, int) else values, first) if check else None
    if problem:
        raise damaged(store, array, touched[0], problem, describe)
    return values


def damaged(
    store: str | os.PathLike,
    array: zarr.Array,
    chunk: Chunk,
    problem: str,
    describe: Callable[[range], str] | None = None,
) -> ChunkError:
    """The ChunkError for a damaged chunk, with what to run."""
    rows = chunk.rows
    episodes = (
        describe(rows)
        if describe
        else (f"episode {rows.start}" if len(rows) == 1 else f"episodes {rows.start}–{rows.stop - 1}")
    )
    return ChunkError(
        f"{store}: array {array.basename!r}, chunk {chunk.key} ({episodes}) is damaged: {problem}; "
        + VERIFY.format(store=store)
    )


#: What to run on a damaged store.
VERIFY = "check and repair the store with: python -m flows.build_datasets --verify {store} LOG_DIR"


def write_rows(array: zarr.Array, start: int, values: np.ndarray) -> None:
    """Append `values` as rows `start`… of `array` (whose committed length is `start`), invisibly until the
    caller resizes it (`commit_rows`)."""
    staged(array, start + len(values))[start : start + len(values)] = values


def commit_rows(array: zarr.Array, rows: int) -> None:
    """Make the first `rows` rows the array's shape (what every reader then sees)."""
    if array.shape[0] != rows:
        array.resize((rows, *array.shape[1:]))
