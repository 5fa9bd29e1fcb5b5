"""The learned forward model: VQ-VAE + conditional PixelCNN behind the planner's seam (docs/protocol.md §2).

Given the last four observed frames it encodes them, chains the prior k steps ahead (each predicted grid joins
the context), and decodes the k grids. Variants of the paper's Table 1:

* *Mid* (`samples=0`): the decoder's mid-point frames;
* *N samples*: also N samples from the decoder's likelihood; obstacles are the pixel-wise union over the
  mid-point and the samples (conservative: the largest obstacle value wherever any of them shows one), and the
  goal is drawn at the median of the goal positions found in them.

Code grids are chosen greedily (argmax) as in the reference. Beyond the paper, `futures = N` also samples N
stochastic futures from the prior itself (codes drawn at `temperature`, 1 unless set) and merges their decoded
frames with the greedy one the same way as decoder samples — or, with `marginal`, through their obstacle
probabilities: the pixels whose probability averaged over the futures (an estimate of the prior's marginal, not its
greedy path's) reaches the occupancy threshold join the greedy frames, and the futures' own frames do not.
`occupancy = p` alone marks as obstacles the pixels that the prior gives a probability of at least p of holding
one, along the greedy future (the prior's own uncertainty where the argmax hides it: when an obstacle's next
position is split over several codes, the argmax can be the empty patch). It needs patch-local codes, each decoding
to its own patch. `margin = m` widens every predicted obstacle by m pixels along its lane (a row), both ways: the
prior places a slow obstacle's sub-pixel phase a pixel off often enough that its neighbours are worth avoiding.
`span = n` keeps occupancy and margin on the first n predicted frames (0: every frame). Each configuration has its
own caution (its registry entry), chosen on validation episodes.
"""

from __future__ import annotations

import hashlib
import os
import weakref
from collections import OrderedDict
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import torch

from dynplan.data.history import last_frames
from dynplan.env.config import FREE, GOAL_VALUE
from dynplan.models import checkpoint
from dynplan.models.batched import BatchedWeights, batched_weights, generate_batched
from dynplan.models.caution import Caution
from dynplan.models.checkpoint import CheckpointError, pretrained_path
from dynplan.models.generation import KernelWeights, generate_fast, kernel_weights
from dynplan.models.pixelcnn import ConditionalPixelCNN, draw_uniforms
from dynplan.models.registry import caution_for
from dynplan.models.vqvae import VQVAE
from dynplan.planning.forward import Prediction, goal_centres

#: The value drawn where only the occupancy shows an obstacle: a sedan's, the commonest class (the planner sees
#: any value other than free and goal as an obstacle).
UNSURE_OBSTACLE = 144


def merge_samples(mid: np.ndarray, samples: np.ndarray) -> np.ndarray:
    """mid (k, H, W) and samples (n, k, H, W) uint8 → the conservative frames (k, H, W) the planner sees."""
    views = np.concatenate([mid[None], samples])  # (n + 1, k, H, W)
    obstacles = np.where((views != FREE) & (views != GOAL_VALUE), views, 0).max(axis=0)
    merged = np.zeros_like(mid)
    k, H, W = mid.shape
    centres = goal_centres(views.reshape(-1, H, W)).reshape(len(views), k, 2)  # NaN where no goal
    for t in range(k):
        found = centres[:, t][~np.isnan(centres[:, t, 0])]
        if len(found):
            # The block's centre is its lower-left pixel + 0.5: rounding (centre − 0.5) is flooring the centre.
            y, x = np.floor(np.median(found, axis=0)).astype(int)
            y, x = min(max(y, 0), H - 2), min(max(x, 0), W - 2)
            merged[t, y : y + 2, x : x + 2] = GOAL_VALUE
    return np.where(obstacles > 0, obstacles, merged)


def widen_obstacles(frames: np.ndarray, margin: int) -> np.ndarray:
    """frames (..., H, W) uint8 with every obstacle pixel also drawn on the `margin` pixels either side of it in its
    row (the largest obstacle value where several reach; over free road and goal alike)."""
    obstacles = np.where((frames != FREE) & (frames != GOAL_VALUE), frames, 0)
    widened = obstacles.copy()
    for shift in range(1, margin + 1):
        np.maximum(widened[..., shift:], obstacles[..., :-shift], out=widened[..., shift:])
        np.maximum(widened[..., :-shift], obstacles[..., shift:], out=widened[..., :-shift])
    return np.where(widened > 0, widened, frames)


#: Grids generated together from which the batched generation (`batched.generate_batched`: matrix–matrix products
#: over the batch) is used on the CPU instead of the compiled kernel (whose row blocks run on torch's threads);
#: measured by `python -m dynplan.bench generation` (on 2 cores the batched generation is cheaper per grid of the
#: default prior from between 32 and 100 rows).
BATCHED_FROM = 64

_LAYOUTS: weakref.WeakKeyDictionary[ConditionalPixelCNN, dict] = weakref.WeakKeyDictionary()

#: Observed frames whose codes each tokenizer keeps (the most recently used): a lockstep batch of episodes needs
#: `context` per episode at each step, and an evaluation's cases replay the same recorded worlds.
ENCODED_FRAMES = 4096
_ENCODED: weakref.WeakKeyDictionary[VQVAE, OrderedDict] = weakref.WeakKeyDictionary()


@contextmanager
def one_thread() -> Iterator[None]:
    """Within the block torch runs on one thread: the same sums whatever the caller's threads and batch, so a result
    replays exactly (on two threads a convolution over an odd batch of frames splits its sums otherwise)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


def _frozen(prior: ConditionalPixelCNN, layout: str) -> KernelWeights | BatchedWeights:
    """The prior's weights laid out for generation — "kernel" for the compiled kernel, else a device for the batched
    generation — once per prior: a world model never trains its prior, and an evaluation builds one model per
    episode on the same prior."""
    layouts = _LAYOUTS.setdefault(prior, {})
    if layout not in layouts:
        layouts[layout] = kernel_weights(prior) if layout == "kernel" else batched_weights(prior, layout)
    return layouts[layout]


def check_device(name: str) -> str:
    """`name` as torch spells the device, or a ValueError naming it and what is available."""
    try:
        device = torch.device(name)
    except (RuntimeError, TypeError):
        raise ValueError(f"device must be a torch device such as 'cpu' or 'cuda', got {name!r}") from None
    if device.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"device {name!r}: no CUDA GPU is available here (use 'cpu')")
    if device.type not in ("cpu", "cuda"):
        raise ValueError(f"device must be 'cpu' or 'cuda[:N]', got {name!r}")
    return str(device)


def observation_stream(seed: int, observation: bytes, purpose: str, index: int = 0) -> torch.Generator:
    """The random stream a model with `seed` draws from for one purpose ("samples": the decoder samples of predicted
    frame `index`; "futures": sampled future `index`) given an observation (its context codes' bytes), seeded by a hash
    of all four. The draws are a function of what was observed, not of what came before: the cases of an
    evaluation that share a world (and so a model seed) and have seen the same frames get the same draws, and fewer
    samples, futures or frames are a prefix of more."""
    key = f"{seed}/{purpose}/{index}".encode()
    state = int.from_bytes(hashlib.blake2b(observation, digest_size=8, key=key[:64]).digest(), "little")
    return torch.Generator().manual_seed(state)


class LearnedWorldModel:
    """Forward model from a trained tokenizer and prior. `predict` takes the observed frames (at least the
    last 4) and returns uint8 (k, H, W) frames as the planner sees them. The prior's grids are generated by the
    compiled kernel for fewer than `BATCHED_FROM` rows, else by the batched generation on `device` (always there
    when `device` is not the CPU)."""

    def __init__(self, tokenizer: VQVAE, prior: ConditionalPixelCNN, samples: int = 0, futures: int = 0,
                 seed: int = 0, occupancy: float = 0.0, margin: int = 0, device: str = "cpu",
                 marginal: bool = False, temperature: float = 1.0, span: int = 0):  # fmt: skip
        if tokenizer.config.codebook_size != prior.config.codebook_size:
            raise ValueError(f"the prior predicts {prior.config.codebook_size} codes; the tokenizer has "
                             f"{tokenizer.config.codebook_size}")  # fmt: skip
        if samples < 0 or futures < 0:
            raise ValueError(f"samples and futures must be >= 0, got {samples}, {futures}")
        Caution(occupancy=occupancy, margin=margin, span=span)  # the ranges' one home: a bad value is a ConfigError
        if occupancy and not (tokenizer.config.local and tokenizer.config.n_codebooks == 1):
            raise ValueError("occupancy needs a tokenizer with patch-local codes (local=True, n_codebooks=1), "
                             f"got {tokenizer.config.name!r}")  # fmt: skip
        if marginal and not (futures and occupancy):
            raise ValueError("marginal merges sampled futures through their mean obstacle probability at the "
                             f"occupancy threshold: it needs futures >= 1 and occupancy > 0, got futures={futures}, "
                             f"occupancy={occupancy}")  # fmt: skip
        if not 0.0 < temperature <= 2.0:
            raise ValueError(f"temperature (the sampled futures' codes) must be in (0, 2], got {temperature}")
        self.tokenizer, self.prior = tokenizer.eval(), prior.eval()
        self.samples, self.futures, self.occupancy, self.margin = samples, futures, occupancy, margin
        self.marginal, self.temperature, self.span, self.seed = marginal, temperature, span, seed
        self.generator = torch.Generator().manual_seed(seed)  # `predict_codes`' sampled futures
        settings = {
            "marginal": marginal,
            "occupancy": occupancy,
            "margin": margin,
            "span": span if occupancy or margin else 0,
            "temperature": temperature if temperature != 1.0 and futures else 0,
        }
        shown = "".join(f", {key}={value}" for key, value in settings.items() if value)
        self.name = f"model(samples={samples}, futures={futures}{shown})"
        self.context = prior.config.context
        self.device = check_device(device)
        self._code_obstacles: torch.Tensor | None = None

    @torch.inference_mode()
    def code_obstacles(self) -> torch.Tensor:
        """(K, ph · pw) float: 1 where a code's decoded patch shows an obstacle (patch-local codes only)."""
        if self._code_obstacles is None:
            patches = self.tokenizer.decode(torch.arange(self.tokenizer.config.codebook_size).reshape(-1, 1, 1))
            self._code_obstacles = ((patches != FREE) & (patches != GOAL_VALUE)).flatten(1).float()
        return self._code_obstacles

    @torch.inference_mode()
    def encode_context(self, observed: np.ndarray) -> torch.Tensor:
        """The code grids (context, h, w) of the last `context` observed frames (frame 0 repeated before a short
        observation's start)."""
        return self._encode_contexts([observed])[0]

    def _encode_contexts(self, observed: Sequence[np.ndarray]) -> torch.Tensor:
        """(E, context, h, w) code grids of the last `context` frames of each of E observations (the first frame
        repeated before a shorter one's start, as the prior was trained: `dynplan.data.history`), in one pass over
        the frames the tokenizer has not encoded lately (`_ENCODED`: the next decision's context shares all but
        one frame with this one's)."""
        frames = [np.ascontiguousarray(frame) for o in observed for frame in last_frames(o, self.context)]
        known = _ENCODED.setdefault(self.tokenizer, OrderedDict())
        keys = [(frame.shape, frame.tobytes()) for frame in frames]
        missing = list(dict.fromkeys(key for key in keys if key not in known))
        if missing:
            rows = {key: i for i, key in enumerate(keys)}
            with one_thread():
                codes = self.tokenizer.encode(torch.from_numpy(np.stack([frames[rows[key]] for key in missing])))
            known.update(zip(missing, codes, strict=True))
        grids = torch.stack([known[key] for key in keys])
        for key in keys:
            known.move_to_end(key)
        while len(known) > ENCODED_FRAMES:
            known.popitem(last=False)
        return grids.reshape(len(observed), self.context, *grids.shape[1:])

    @torch.inference_mode()
    def predict_codes(self, observed: np.ndarray, k: int, futures: int = 1, temperature: float = 0.0) -> torch.Tensor:
        """(futures, k, h, w) code grids of frames t+1 … t+k from the last `context` observed frames: greedy at
        temperature 0 (one future), else `futures` futures sampled at `temperature` from the model's stream."""
        context = self.encode_context(observed)[None].expand(futures, -1, -1, -1)
        return self._chain(context, [k] * futures, temperature, [(self.generator, futures)] if temperature else [])[0]

    def _chain(self, context: torch.Tensor, lengths: Sequence[int], temperature: float = 0.0,
               streams: Sequence[tuple[torch.Generator, int]] = (),
               occupancy: bool = False) -> tuple[torch.Tensor, np.ndarray | None]:  # fmt: skip
        """The prior chained ahead from `context` (B, context, h, w), row b for `lengths[b]` grids, each grid joining
        its row's context: codes (B, max length, h, w), zero past a row's length. Sampled (`temperature` > 0), the
        rows form consecutive groups, one per stream (generator, rows): a group draws its numbers from its own
        generator, one grid after another and only for its rows' length (equal within a group), so a shorter chain
        is a longer one's prefix. With `occupancy`, also each grid's per-pixel obstacle probability (B, max length,
        H, W), from the generation's own logits."""
        B, _, h, w = context.shape
        lengths = np.asarray(lengths)
        steps = int(lengths.max())
        table = self.code_obstacles() if occupancy else None
        grids = torch.zeros(B, steps, h, w, dtype=torch.long)
        ph, pw = self.tokenizer.patch
        probability = np.zeros((B, steps, h * ph, w * pw), np.float32) if occupancy else None
        firsts = np.cumsum([0, *(rows for _, rows in streams)])[:-1]
        stream_lengths = lengths[firsts] if len(streams) else lengths[:0]  # a group's rows share their length
        for step in range(steps):
            live = np.flatnonzero(lengths > step)
            rows = live if len(live) < B else slice(None)
            uniforms = None
            if temperature:
                pairs = zip(streams, stream_lengths, strict=True)
                uniforms = torch.cat([draw_uniforms(count, h, w, temperature, generator)
                                      for (generator, count), n in pairs if n > step])  # fmt: skip
            batched = self.device != "cpu" or len(live) >= BATCHED_FROM
            weights = _frozen(self.prior, self.device if batched else "kernel")
            if batched:
                grid = generate_batched(self.prior, context[rows], temperature, None, weights, uniforms, table)
            else:
                grid = generate_fast(self.prior, context[rows], temperature, None, weights, uniforms,
                                     None if table is None else table.numpy())  # fmt: skip
            if occupancy:
                grid, expected = grid
                expected = np.asarray(expected).reshape(len(live), h, w, ph, pw)
                probability[live, step] = expected.transpose(0, 1, 3, 2, 4).reshape(len(live), h * ph, w * pw)
            grids[live, step] = grid
            if len(live) == B:
                context = torch.cat([context[:, 1:], grid[:, None]], dim=1)
            else:  # the finished rows keep their context; no step reads it again
                context = context.clone()
                context[live] = torch.cat([context[live, 1:], grid[:, None]], dim=1)
        return grids, probability

    def _cautious(self, k: int) -> int:
        """How many of k predicted frames the caution covers (`span`; 0: all)."""
        return min(k, self.span) if self.span else k

    def _unsure(self, probability: np.ndarray) -> np.ndarray:
        """(k, H, W) uint8 frames of the unsure obstacles: where the obstacle `probability` (k, H, W) reaches the
        occupancy, within the caution's span."""
        unsure = probability >= self.occupancy
        unsure[self._cautious(len(unsure)) :] = False
        return np.where(unsure, UNSURE_OBSTACLE, FREE).astype(np.uint8)

    def cost(self, k: int) -> int:
        """The grids a k-frame prediction generates (the greedy chain and every future): how a shared batch's time
        is split between the episodes that asked for it."""
        return k * (1 + self.futures)

    @property
    def batch_key(self) -> tuple:
        """Models with equal keys can predict together (`predict_batch`): the same weights, on the same device."""
        return id(self.tokenizer), id(self.prior), self.device

    @torch.inference_mode()
    def predict(self, observed: np.ndarray, k: int) -> Prediction:
        """Frames t+1 … t+k: the greedy future's mid-point, merged with the model's decoder samples and with the
        mid-points of its sampled futures, then its caution applied. The batch of one of `predict_batch`."""
        return LearnedWorldModel.predict_batch([self], [observed], [k])[0]

    @staticmethod
    @torch.inference_mode()
    def predict_batch(models: Sequence[LearnedWorldModel], observed: Sequence[np.ndarray],
                      ks: Sequence[int]) -> list[Prediction]:  # fmt: skip
        """Each model's prediction of its own episode (`observed[e]`, `ks[e]` frames ahead), computed together by
        models on the same weights (equal `batch_key`) whatever their settings: one encoding; one greedy chain
        (with its occupancy) per distinct observation, as long as the longest horizon asking for it; one set of
        decoder samples and one of sampled futures per distinct observation and model seed, as many as the most any
        model asks for; one decoding. Every draw comes from the observation's own stream (`observation_stream`), so
        a prediction does not depend on which others share its batch (up to float summation order in the batched
        generation)."""
        first = models[0]
        if any(m.batch_key != first.batch_key for m in models):
            raise ValueError("predict_batch: the models differ in weights or device; group them by batch_key")
        if not len(models) == len(observed) == len(ks):
            raise ValueError(f"predict_batch: {len(models)} models, {len(observed)} observations, {len(ks)} horizons")
        if min(ks) < 1:
            raise ValueError(f"predict_batch: every horizon must be >= 1, got {min(ks)}")
        tokenizer, E = first.tokenizer, len(models)
        context = first._encode_contexts(observed)  # (E, context, h, w)
        keys = [context[e].numpy().tobytes() for e in range(E)]
        index: dict[bytes, int] = {}
        which = [index.setdefault(key, len(index)) for key in keys]  # each episode's distinct observation
        firsts = [which.index(u) for u in range(len(index))]
        lengths = np.zeros(len(index), np.int64)
        np.maximum.at(lengths, which, ks)
        unique = context[firsts]
        greedy, probability = first._chain(unique, lengths, occupancy=any(m.occupancy and not m.marginal
                                                                           for m in models))  # fmt: skip
        starts = np.cumsum([0, *lengths])
        with one_thread():
            params = tokenizer.decode_params(torch.cat([greedy[u, :n] for u, n in enumerate(lengths)]))
        mid = tokenizer.pixel.mid(params).numpy()
        frames_of = [np.arange(starts[u], starts[u] + k) for u, k in zip(which, ks, strict=True)]
        others: list[list[np.ndarray]] = [[] for _ in range(E)]
        drawers: dict[tuple[int, int], list[int]] = {}  # (distinct observation, model seed) → the models sampling
        for e, model in enumerate(models):
            if model.samples:
                drawers.setdefault((which[e], model.seed), []).append(e)
        by_count: dict[int, list[tuple[tuple[int, int], int]]] = {}  # samples → ((observation, seed), frames)
        for key, members in drawers.items():
            most = max(models[e].samples for e in members)
            by_count.setdefault(most, []).append((key, max(ks[e] for e in members)))
        drawn: dict[tuple[int, int], np.ndarray] = {}
        for count, entries in by_count.items():  # each observation's samples once: the most any model asks for
            shape = torch.Size((1, *params.shape[1:]))
            noise = [tokenizer.pixel.noise(shape, count, observation_stream(seed, keys[firsts[u]], "samples", f))
                     for (u, seed), n in entries for f in range(n)]  # fmt: skip
            joined = tuple(torch.cat(parts, dim=1) for parts in zip(*noise, strict=True))  # batch axis: 1
            rows = torch.from_numpy(np.concatenate([np.arange(starts[u], starts[u] + n) for (u, _), n in entries]))
            samples = tokenizer.pixel.sample_with(params[rows], joined).numpy()  # (count, Σ frames, H, W)
            offsets = np.cumsum([0, *(n for _, n in entries)])
            for j, (key, _) in enumerate(entries):
                drawn[key] = samples[:, offsets[j] : offsets[j + 1]]
        for key, members in drawers.items():
            for e in members:
                others[e].append(drawn[key][: models[e].samples, : ks[e]])
        for e, model in enumerate(models):
            if model.occupancy and not model.marginal:
                others[e].append(model._unsure(probability[which[e], : ks[e]])[None])
        # (distinct observation, model seed, temperature) → the models with futures
        dreamers: dict[tuple[int, int, float], list[int]] = {}
        for e, model in enumerate(models):
            if model.futures:
                dreamers.setdefault((which[e], model.seed, model.temperature), []).append(e)
        futures_by: dict[tuple[int, float], list] = {}  # (futures, temperature) → ((observation, seed, T), frames)
        for key, members in dreamers.items():
            most = max(models[e].futures for e in members)
            futures_by.setdefault((most, key[2]), []).append((key, max(ks[e] for e in members)))
        for (count, temperature), entries in futures_by.items():  # each observation's futures once: the most asked
            streams = [
                (observation_stream(seed, keys[firsts[u]], "futures", j), 1)
                for (u, seed, _), _ in entries
                for j in range(count)
            ]  # one stream per future: fewer are a prefix
            context_rows = torch.tensor([u for (u, _, _), _ in entries]).repeat_interleave(count)
            members = [e for key, _ in entries for e in dreamers[key]]
            sampled, chance = first._chain(unique[context_rows], np.repeat([n for _, n in entries], count),
                                           temperature, streams,
                                           occupancy=any(models[e].marginal for e in members))  # fmt: skip
            futures = {}
            if not all(models[e].marginal for e in members):  # some merge the futures' frames: decode them
                with one_thread():
                    decoded = tokenizer.decode(torch.cat([sampled[j * count : (j + 1) * count, :n].flatten(0, 1)
                                                          for j, (_, n) in enumerate(entries)])).numpy()  # fmt: skip
                offsets = np.cumsum([0, *(count * n for _, n in entries)])
                futures = {key: decoded[offsets[j] : offsets[j + 1]].reshape(count, n, *mid.shape[1:])
                           for j, (key, n) in enumerate(entries)}  # fmt: skip
            for j, (key, _) in enumerate(entries):
                for e in dreamers[key]:
                    model = models[e]
                    if model.marginal:  # the mean over this model's futures (a prefix of the group's)
                        marginal = chance[j * count : j * count + model.futures, : ks[e]].mean(axis=0)
                        others[e].append(model._unsure(marginal)[None])
                    else:
                        others[e].append(futures[key][: model.futures, : ks[e]])
        predictions = []
        for e, model in enumerate(models):
            frames = mid[frames_of[e]]
            if others[e]:
                frames = merge_samples(frames, np.concatenate(others[e]))
            if model.margin:
                near = model._cautious(ks[e])
                frames = np.concatenate([widen_obstacles(frames[:near], model.margin), frames[near:]])
            predictions.append(Prediction.from_frames(frames))
        return predictions

    @torch.inference_mode()
    def obstacle_probability(self, context: torch.Tensor, grids: torch.Tensor) -> np.ndarray:
        """Per pixel, the prior's probability of an obstacle in each of the k predicted frames, given the observed
        `context` codes (c, h, w) and, before each position, the greedy `grids` (k, h, w) themselves: one
        teacher-forced pass over all k frames (what `predict` takes from the generation's own logits instead).
        Returns float32 (k, H, W)."""
        windows = torch.cat([context, grids]).unfold(0, self.context, 1)[: len(grids)]  # (k, h, w, c)
        k, h, w = grids.shape
        ph, pw = self.tokenizer.patch
        with one_thread():
            logits = self.prior.teacher_forced_logits(windows.permute(0, 3, 1, 2), grids)  # (k, h, w, K)
            patches = (torch.softmax(logits, dim=-1) @ self.code_obstacles()).reshape(k, h, w, ph, pw)
        return patches.permute(0, 1, 3, 2, 4).reshape(k, h * ph, w * pw).numpy()


def world_model_paths(model: str, model_dir: str | os.PathLike | None = None) -> tuple[Path, Path]:
    """The (VQ-VAE, PixelCNN) checkpoints of configuration `model`: `model_dir/<model>/{vqvae,pixelcnn}.pt` when a
    pipeline trained its own, else the committed pretrained ones."""
    if model_dir is not None:
        return Path(model_dir) / model / "vqvae.pt", Path(model_dir) / model / "pixelcnn.pt"
    return pretrained_path("vqvae", model), pretrained_path("pixelcnn", model)


def world_model_parts(paths: tuple[Path, Path], model: str = "default") -> tuple:
    """The (tokenizer, prior) in `paths`, loaded once per content of the files (see `checkpoint.cached`)."""
    missing = [str(p) for p in paths if not Path(p).exists()]
    if missing:
        raise CheckpointError(f"no world model checkpoints at {', '.join(missing)}; train them with "
                              f"`python -m flows.train vqvae|pixelcnn --model {model}` or the collect-train-eval "
                              "flow")  # fmt: skip
    tokenizer = checkpoint.cached(checkpoint.VQVAE_KIND, paths[0])
    prior = checkpoint.cached(checkpoint.PIXELCNN_KIND, paths[1])
    if tokenizer.config.codebook_size != prior.config.codebook_size:
        raise CheckpointError(
            f"{paths[1]}: predicts {prior.config.codebook_size} code values, but the tokenizer {paths[0]} has "
            f"{tokenizer.config.codebook_size}: they are not one world model"
        )
    return tokenizer, prior


def load_world_model(path: str | os.PathLike | None = None, model: str = "default", samples: int = 0, futures: int = 0,
                     seed: int = 0, caution: Mapping[str, float] | None = None, device: str = "cpu",
                     marginal: bool = False, temperature: float = 1.0) -> LearnedWorldModel:  # fmt: skip
    """The learned forward model: from a folder holding `vqvae.pt` and `pixelcnn.pt`, or (None) the committed
    pretrained checkpoints of the configuration `model` ("default" or "paper"), with the configuration's own
    caution (its registry entry) except where `caution` (field → value) overrides it. Weights are loaded once per
    content and shared by every model built on them; `device` is where batched generation runs ("cuda" on a GPU)."""
    paths = world_model_paths(model) if path is None else (Path(path) / "vqvae.pt", Path(path) / "pixelcnn.pt")
    tokenizer, prior = world_model_parts(paths, model)
    return LearnedWorldModel(tokenizer, prior, samples, futures, seed, **caution_for(model, caution).model_dump(),
                             device=device, marginal=marginal, temperature=temperature)  # fmt: skip
