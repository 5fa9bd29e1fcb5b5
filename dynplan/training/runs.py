"""Where a training run lives: its folder is named by what determines its result — (dataset fingerprint and, for
the prior, the codes it trains on; config; batches per epoch, seed, validation size, warm start; code version) —
so a rerun with the same inputs finds the run, an interrupted one resumes in it, and a larger epoch count
extends it. How it is run (epochs, time cap, threads, device) is not part of the name: a run started on one
machine resumes on another.
"""

from __future__ import annotations

from pathlib import Path

import zarr

from dynplan.config import digest
from dynplan.data.store import fingerprint
from dynplan.files import sha256_file
from dynplan.training.pixelcnn import CODE_VERSION as PIXELCNN_CODE_VERSION
from dynplan.training.vqvae import CODE_VERSION as VQVAE_CODE_VERSION

#: Budget fields that say how a run is executed, not what it produces.
NOT_DETERMINING = ("epochs", "max_minutes", "threads", "device")


def _run_dir(kind: str, out: str, config: dict, budget: dict, sources: list, code_version: str) -> Path:
    """Where a training run lives: named by what determines its result (the epoch count excepted)."""
    determining = {k: v for k, v in budget.items() if k not in NOT_DETERMINING}
    if determining.get("init_from"):  # a warm start is identified by the weights it starts from, not their path
        determining["init_from"] = sha256_file(determining["init_from"])
    key = digest(*sources, config, determining, code_version)
    return Path(out) / f"{kind}-{config['name']}-{key[:12]}"


def vqvae_run_dir(store: str, out: str, config: dict, budget: dict) -> Path:
    return _run_dir("vqvae", out, config, budget, [fingerprint(store)], VQVAE_CODE_VERSION)


def pixelcnn_run_dir(store: str, codes: str, out: str, config: dict, budget: dict) -> Path:
    attrs = zarr.open_group(store, mode="r", use_consolidated=False)[codes].attrs
    sources = [fingerprint(store), attrs["source_digest"], attrs["checkpoint_sha256"]]
    return _run_dir("pixelcnn", out, config, budget, sources, PIXELCNN_CODE_VERSION)
