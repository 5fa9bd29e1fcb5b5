"""The tokenizer's view of what was observed: the code grids of each observation's last frames, with the frames it
encoded lately kept (a lockstep batch asks for `context` frames per episode at each step, and the next decision's
context shares all but one frame with this one's)."""

from __future__ import annotations

import weakref
from collections import OrderedDict
from collections.abc import Sequence

import numpy as np
import torch

from dynplan.data.history import last_frames
from dynplan.models.device import one_thread
from dynplan.models.vqvae import VQVAE

#: Observed frames whose codes each tokenizer keeps (the most recently used): a lockstep batch of episodes needs
#: `context` per episode at each step, and an evaluation's cases replay the same recorded worlds.
ENCODED_FRAMES = 4096
_ENCODED: weakref.WeakKeyDictionary[VQVAE, OrderedDict] = weakref.WeakKeyDictionary()


@torch.inference_mode()
def encode_contexts(tokenizer: VQVAE, observed: Sequence[np.ndarray], context: int) -> torch.Tensor:
    """(E, context, h, w) code grids of the last `context` frames of each of E observations (t+1, H, W) (the first
    frame repeated before a shorter one's start, as the prior was trained: `dynplan.data.history`), in one pass
    over the frames `tokenizer` has not encoded lately."""
    frames = [np.ascontiguousarray(frame) for o in observed for frame in last_frames(o, context)]
    known = _ENCODED.setdefault(tokenizer, OrderedDict())
    keys = [(frame.shape, frame.tobytes()) for frame in frames]
    missing = list(dict.fromkeys(key for key in keys if key not in known))
    if missing:
        rows = {key: i for i, key in enumerate(keys)}
        with one_thread():
            codes = tokenizer.encode(torch.from_numpy(np.stack([frames[rows[key]] for key in missing])))
        known.update(zip(missing, codes, strict=True))
    grids = torch.stack([known[key] for key in keys])
    for key in keys:
        known.move_to_end(key)
    while len(known) > ENCODED_FRAMES:
        known.popitem(last=False)
    return grids.reshape(len(observed), context, *grids.shape[1:])
