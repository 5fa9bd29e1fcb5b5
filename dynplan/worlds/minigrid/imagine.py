"""The learned technique's futures: the world model's prior chained k rooms ahead from the frames seen, sampled.

Each sampled future is a room the prior drew cell by cell; with it comes, for every cell, the chance of a ball the
prior gave as it drew that cell (`Imagined.balls`: the softmax it sampled from, given the cells drawn before and the
rooms before). The planner plans against those chances, not the 0/1 draws: averaged over a few samples they
estimate each cell's chance of a ball with far less noise than counting balls in the same samples would.
"""

from __future__ import annotations

import os
from functools import cached_property

import numpy as np
import torch

from dynplan.models.chain import ChainSpec, chain
from dynplan.models.encoding import encode_contexts
from dynplan.models.streams import observation_stream
from dynplan.models.weights import world_model_paths
from dynplan.models.world_model import world_model_parts
from dynplan.worlds.minigrid.futures import Imagined
from dynplan.worlds.minigrid.grid import PIXEL_VALUES
from dynplan.worlds.minigrid.models import NAME

BALL = PIXEL_VALUES["ball"]


class MiniGridModel:
    """The learned world model of MiniGrid (the `minigrid` configuration) from `model_dir` (holding `vqvae.pt` and
    `pixelcnn.pt`; None: the committed weights), its draws seeded by `seed` and what it has seen."""

    def __init__(self, model_dir: str | os.PathLike | None = None, seed: int = 0):
        self.tokenizer, self.prior = world_model_parts(world_model_paths(NAME, model_dir), NAME)
        self.seed = seed

    @cached_property
    def _code_balls(self) -> torch.Tensor:
        """(K, ph · pw): 1 where a cell of a code's patch is a ball."""
        with torch.inference_mode():
            cells = self.tokenizer.decode(torch.arange(self.prior.config.codebook_size).reshape(-1, 1, 1))
        return (cells == BALL).flatten(1).float()

    @torch.inference_mode()
    def imagine(self, seen: np.ndarray, k: int, samples: int) -> Imagined:
        """`samples` futures of the k rooms after the last of `seen` (t + 1, H, W), the frames up to now."""
        context = encode_contexts(self.tokenizer, [seen], self.prior.config.context)
        generator = observation_stream(self.seed, context.numpy().tobytes(), "futures")
        spec = ChainSpec("cpu", [(generator, samples)], self._code_balls, self.tokenizer.patch)
        codes, balls = chain(self.prior, context.expand(samples, -1, -1, -1), [k] * samples, spec)
        rooms = self.tokenizer.decode(codes.flatten(0, 1)).numpy().reshape(samples, k, *seen.shape[1:])
        now = np.broadcast_to(seen[-1], (samples, 1, *seen.shape[1:]))
        return Imagined(
            np.concatenate([now, rooms.astype(np.uint8)], axis=1),
            np.concatenate([(now == BALL).astype(np.float32), balls], axis=1),
        )
