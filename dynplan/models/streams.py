"""The random streams a learned world model draws from, one per purpose and observation.

A model's draws are a function of what its episode observed, not of what came before: the cases of an evaluation
that share a world (and so a model seed) and have seen the same frames get the same draws, whichever other episodes
share their batch, and fewer samples, futures or frames are a prefix of more.
"""

from __future__ import annotations

import hashlib

import torch


def observation_stream(seed: int, observation: bytes, purpose: str, index: int = 0) -> torch.Generator:
    """The stream a model with `seed` draws from for one purpose ("samples": the decoder samples of predicted frame
    `index`; "futures": sampled future `index`) given an observation (its context codes' bytes), seeded by a hash
    of all four."""
    key = f"{seed}/{purpose}/{index}".encode()
    state = int.from_bytes(hashlib.blake2b(observation, digest_size=8, key=key[:64]).digest(), "little")
    return torch.Generator().manual_seed(state)
