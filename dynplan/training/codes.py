"""The Z-code store: every frame of the frames store encoded by a trained VQ-VAE, as a Zarr array beside it.

`codes_<name>` has shape (episode, time, h, w), uint16, one
chunk per episode, and records which checkpoint (path and SHA-256) made it and a digest of the frames store's
episodes it encodes. Encoding runs with dask, one task per episode chunk, on whatever scheduler is active.
Rebuilding with the same checkpoint only encodes episodes added to the frames store since; another checkpoint,
or a frames store whose earlier episodes changed, re-encodes everything.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import dask.array as da
import numpy as np
import torch
import zarr

from dynplan.data.chunks import COMPRESSORS, VERIFY, ChunkError, check_present, commit_rows, staged
from dynplan.data.contents import pixel_check
from dynplan.data.store import committed_checksums, episodes_digest
from dynplan.files import sha256_file
from dynplan.models.checkpoint import VQVAE_KIND, cached
from dynplan.progress import progress


def _model(checkpoint: str):
    return cached(VQVAE_KIND, checkpoint)


def _encode_block(block: np.ndarray, checkpoint: str, store: str, start: int, block_info=None) -> np.ndarray:
    torch.set_num_threads(1)  # dask runs one block per thread/worker already
    model = _model(checkpoint)
    first = start + (block_info[0]["array-location"][0][0] if block_info else 0)  # the batch's episodes from `start`
    problem = pixel_check(model.config.values)(block, first)
    if problem:  # encoded, it would be a code of some other picture
        raise ChunkError(f"{store}: array 'frames': {problem}; {VERIFY.format(store=store)}")
    E, T = block.shape[:2]
    codes = model.encode(torch.from_numpy(np.ascontiguousarray(block.reshape(E * T, *block.shape[2:]))))
    return codes.numpy().astype(np.uint16).reshape(E, T, *codes.shape[1:])


def build_codes(store: str | os.PathLike, checkpoint: str | os.PathLike, name: str, batch: int = 100) -> str:
    """Encode the store's frames with the VQ-VAE in `checkpoint` into the array `codes_<name>`, `batch` episodes
    at a time; returns its name."""
    store, checkpoint = str(store), str(Path(checkpoint).resolve())
    model = _model(checkpoint)
    h, w = model.config.grid
    group = zarr.open_group(store, mode="a", use_consolidated=False)
    frames = group["frames"]
    checksums = committed_checksums(store)
    E, T = len(checksums), frames.shape[1]
    array_name = f"codes_{name}"
    sha = sha256_file(checkpoint)
    done = 0
    if array_name in group and group[array_name].attrs.get("checkpoint_sha256") == sha:
        # Keep what was encoded only if those episodes are still the same ones (the frames store may have been
        # rolled back and refilled since).
        done = int(group[array_name].attrs.get("episodes", 0))
        if done > E or group[array_name].attrs.get("source_digest") != episodes_digest(checksums[:done]):
            done = 0
    check_present(store, frames, range(done, E))  # before anything is written: a missing chunk would encode as blank
    if done == 0:
        if array_name in group:
            del group[array_name]
        dims = ("episode", "time", "code_y", "code_x")
        group.create_array(
            array_name,
            shape=(0, T, h, w),
            chunks=(1, T, h, w),
            dtype="uint16",
            dimension_names=dims,
            compressors=COMPRESSORS,
        )
    codes = group[array_name]
    commit_rows(codes, done)  # rows after the recorded ones are from an interrupted encoding

    def record(stop: int) -> None:  # the first `stop` episodes are encoded, by this checkpoint, from these logs
        codes.attrs.update(
            checkpoint=checkpoint,
            checkpoint_sha256=sha,
            config=model.config.model_dump(),
            episodes=stop,
            source_digest=episodes_digest(checksums[:stop]),
        )
        # Readers that trust the consolidated metadata (zarr's default) see the array and its progress at once.
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="Consolidated metadata is currently not part")
            zarr.consolidate_metadata(store)

    # In batches, each recorded as done once stored: an interrupted encoding resumes after the last batch, and the
    # consolidated metadata names the array from its creation on (a reader checks the two agree).
    record(done)
    for start in progress(range(done, E, batch), total=len(range(done, E, batch)), description=array_name):
        stop = min(E, start + batch)
        source = da.from_zarr(frames)[start:stop]
        encoded = source.map_blocks(_encode_block, checkpoint, store, start, dtype=np.uint16, chunks=(1, T, h, w))
        da.store(encoded, staged(codes, stop), regions=(slice(start, stop),), lock=False)
        commit_rows(codes, stop)  # written, then shown
        record(stop)
    record(E)
    return array_name
