"""Freeway's world model through the road's classes: a tokenizer of the world's 14 values whose padded 40 × 38 grid
has a lane in each 4 code rows, a prior over lane strips chained as the whole grid's, the greedy chain kept per
context (a decision whose observation was predicted continues the last chain), the per-world split, `flows.train`
on a Freeway store, and a learned agent playing the real game with a model trained here."""

from __future__ import annotations

import copy
import itertools
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from dynplan.data.build import build_frame_store_from_logs
from dynplan.data.collect import record_episode
from dynplan.data.datasets import FrameDataset, split_of
from dynplan.data.store import list_logs
from dynplan.models import chain as chain_module
from dynplan.models.chain import ChainSpec, chain, forget_greedy
from dynplan.models.configs import PixelCNNConfig, VQVAEConfig
from dynplan.models.likelihood import Categorical
from dynplan.models.metrics import frame_errors
from dynplan.models.pixelcnn import ConditionalPixelCNN, from_strips, to_strips
from dynplan.models.registry import default_model, models_of, world_model_spec
from dynplan.models.vqvae import VQVAE, padded
from dynplan.world import world
from dynplan.worlds.freeway import game as freeway
from dynplan.worlds.freeway.models import PRIOR, TOKENIZER

pytest.importorskip("ale_py")  # the `atari` extra, in `dev`: installed wherever the suite runs

ROAD, FREEWAY = world("road"), world("freeway")


@settings(max_examples=25, deadline=None)
@given(st.integers(1, 3), st.integers(1, 4), st.integers(1, 4), st.integers(1, 5))
def test_strips_cut_a_grid_into_its_rows_and_back(batch, strips, rows, width):
    grids = torch.randint(0, 50, (batch, 3, strips * rows, width))
    cut = to_strips(grids, rows)
    assert cut.shape == (batch * strips, 3, rows, width)
    assert torch.equal(cut[strips * (batch - 1) + strips - 1], grids[-1, :, -rows:])
    assert torch.equal(from_strips(cut, batch), grids)
    assert to_strips(grids, None) is grids


def test_the_freeway_tokenizer_pads_the_lanes_onto_its_grid_and_decodes_the_frame_size():
    config = TOKENIZER
    assert config.grid == (40, 38) and config.values == tuple(sorted(freeway.PIXEL_VALUES.values()))
    model = VQVAE(config).eval()
    frames = freeway.record_mode(0, 3).frames
    codes = model.encode(frames)
    assert codes.shape == (3, 40, 38)
    decoded = model.decode(codes)
    assert decoded.shape == (3, 154, 152) and set(np.unique(decoded)) <= set(config.values)
    # it encodes a frame as the same weights encode the frame with 6 rows of road above it
    above = padded(frames, config)
    assert (above[:, 154:] == FREEWAY.background).all() and np.array_equal(above[:, :154], frames)
    unpadded = VQVAE(config.model_copy(update={"height": 160, "pad_top": 0})).eval()
    unpadded.load_state_dict(model.state_dict())
    assert np.array_equal(unpadded.encode(above), codes)
    assert isinstance(model.pixel, Categorical) and model.pixel.values == config.values


def test_the_committed_tokenizer_decodes_code_by_code_the_frames_it_decodes_grid_by_grid():
    """A patch-local code decodes to its own patch alone: laying out each code's decoded patch (what a Freeway
    prediction does) gives the mid-point frames of decoding whole grids, padding dropped, for every code."""
    from dynplan.models.world_model import load_world_model

    model = load_world_model(None, "freeway").tokenizer
    K, (h, w) = model.config.codebook_size, model.config.grid
    codes = torch.randint(0, K, (6, h, w), generator=torch.Generator().manual_seed(0))
    codes[0].view(-1)[:K] = torch.arange(K)  # every code, once at least
    by_code = model.decode_by_code(codes)
    assert by_code.shape == (6, 154, 152) and by_code.dtype == torch.uint8
    assert torch.equal(by_code, model.decode(codes))
    with pytest.raises(ValueError, match="patch-local"):
        VQVAE(VQVAEConfig()).decode_by_code(codes[:, :12, :12])


def test_a_tokenizer_of_another_world_is_refused_the_roads_likelihood_or_a_world_it_lacks():
    with pytest.raises(ValueError, match="likelihood 'dmol' snaps to the road's pixel values; the freeway world"):
        VQVAEConfig(world="freeway", height=156, width=152, likelihood="dmol")
    with pytest.raises(ValueError, match="'atari' is not one of dynplan's worlds"):
        VQVAEConfig(world="atari")
    with pytest.raises(ValueError, match=r"frame 154×152 \(padded by 4 rows\) is not divisible"):
        VQVAEConfig(world="freeway", height=154, width=152, pad_top=4, strides=(2, 2, 2), channels=(8, 8, 8),
                    likelihood="categorical")  # fmt: skip
    with pytest.raises(ValueError, match="distinct pixel values"):
        Categorical((6, 0))


def _strip_prior() -> ConditionalPixelCNN:
    torch.manual_seed(0)
    config = PixelCNNConfig(codebook_size=24, channels=8, layers=3, first_kernel=3, embed_dim=4,
                            condition_channels=8, condition_width=5, strip_rows=2)  # fmt: skip
    return ConditionalPixelCNN(config).eval()


def test_a_strip_prior_chains_each_strip_as_a_grid_of_its_own():
    prior = _strip_prior()
    whole = copy.deepcopy(prior)
    whole.config = prior.config.model_copy(update={"strip_rows": None})
    context = torch.randint(0, 24, (2, 4, 6, 7))
    grids, _ = chain(prior, context, [3, 2], ChainSpec())
    strips, _ = chain(whole, to_strips(context, 2), np.repeat([3, 2], 3), ChainSpec())
    assert torch.equal(grids, from_strips(strips, 2))
    assert (grids[1, 2] == 0).all()  # past the second grid's length


def test_the_greedy_chain_is_kept_by_context_and_continued(monkeypatch):
    prior, spec = _strip_prior(), ChainSpec()
    context = torch.randint(0, 24, (1, 4, 6, 7))
    fresh, _ = chain(prior, context, [4], spec)
    generated = []
    real = chain_module._next_grids
    monkeypatch.setattr(chain_module, "_next_grids", lambda p, c, *a: generated.append(len(c)) or real(p, c, *a))
    again, _ = chain(prior, context, [4], spec)
    assert torch.equal(again, fresh) and generated == []  # every grid of this context is kept
    observed = torch.cat([context[:, 1:], fresh[:, :1]], dim=1)  # the first prediction came true
    continued, _ = chain(prior, observed, [4], spec)
    assert torch.equal(continued[:, :3], fresh[:, 1:])
    assert len(generated) == 1 and 1 <= generated[0] <= 3  # only the last grid is new: its distinct strips
    forget_greedy()
    assert torch.equal(chain(prior, observed, [4], spec)[0], continued)  # the same as generated afresh


def test_freeway_splits_by_mode_and_the_road_by_its_seeds_hash():
    validation, held_out = split_of(FREEWAY, np.arange(8), 0.1)
    assert np.flatnonzero(validation).tolist() == [5] and np.flatnonzero(held_out).tolist() == [4]
    validation, held_out = split_of(ROAD, np.arange(100), 0.1)
    assert 3 <= validation.sum() <= 20 and not held_out.any()


def test_each_world_has_its_default_configuration():
    assert default_model("road") == "default" and default_model("freeway") == "freeway"
    assert models_of("freeway") == ["freeway"] and models_of("road") == ["paper", "default"]
    spec = world_model_spec("freeway")
    assert spec.world == "freeway" and spec.prior == PRIOR


@pytest.fixture(scope="module")
def freeway_store(tmp_path_factory):
    """A store of modes 0, 4 and 5, 60 frames each: one training, one held out, one validation episode."""
    root = tmp_path_factory.mktemp("freeway-model")
    for mode in (0, 4, 5):
        record_episode(root / "logs", mode, None, 60, "freeway")
    build_frame_store_from_logs(root / "frames.zarr", list_logs(root / "logs"))
    return root


def test_freeway_trains_on_modes_other_than_the_held_out_and_validation_ones(freeway_store):
    store = freeway_store / "frames.zarr"
    assert FrameDataset(store, "train").seeds[FrameDataset(store, "train").episodes].tolist() == [0]
    assert FrameDataset(store, "validation").seeds[FrameDataset(store, "validation").episodes].tolist() == [5]


@pytest.mark.slow
def test_a_learned_agent_plays_the_game_with_a_model_trained_on_a_freeway_store(freeway_store, prefect_api, capsys):
    """`flows.train` trains Freeway's configuration by default on a Freeway store (and refuses the road's in one
    line); the trained model imagines lanes of Freeway's values, and the learned technique plays the real game."""
    from dynplan.worlds.freeway.evaluation import play_turns, world_model_for
    from dynplan.worlds.freeway.search import ChickenSearch
    from flows.train import main

    store, runs = str(freeway_store / "frames.zarr"), str(freeway_store / "runs")
    with pytest.raises(SystemExit) as exit_:
        main(["vqvae", "--store", store, "--model", "default", "--out", runs])
    assert exit_.value.code == 2
    assert "--model default models the road world's (the freeway world's: freeway)" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_:
        main(["vqvae", "--store", store, "--world", "road", "--out", runs])
    assert exit_.value.code == 2 and "holds the freeway world's episodes, not --world road's" in capsys.readouterr().err
    small = ["--epochs", "1", "--steps-per-epoch", "20", "--out", runs, "--store", store]
    tokenizer = main(["vqvae", *small])
    prior = main(["pixelcnn", *small])
    folder = freeway_store / "model"
    folder.mkdir()
    for path, name in ((tokenizer, "vqvae.pt"), (prior, "pixelcnn.pt")):
        (folder / name).write_bytes(Path(path).read_bytes())
    model = world_model_for("learned", folder)
    episode = freeway.FreewayEpisode(mode=0, noop_start=3)
    turns = list(itertools.islice(play_turns("learned", episode, ChickenSearch(horizon=3), model=model), 6))
    assert all(turn.frames.shape == (4, 154, 152) and turn.decision_ms > 0 for turn in turns)
    assert set(np.unique(np.stack([turn.frames for turn in turns]))) <= set(TOKENIZER.values)
    with pytest.raises(ValueError, match="^technique .oracle. takes no world model$"):
        next(play_turns("oracle", episode, ChickenSearch(horizon=3), model=model))


def test_the_priors_validation_generates_with_the_weights_it_has_now():
    """Generation keeps a prior's laid-out weights and greedy grids per prior object; a prior in training changes
    under the same object, so each validation generates with a copy of the weights as they are then."""
    from dynplan.training.pixelcnn import _validation_scores

    torch.manual_seed(0)
    config = PRIOR.model_copy(update={"channels": 8, "layers": 2, "condition_channels": 8})
    prior, tokenizer = ConditionalPixelCNN(config), VQVAE(TOKENIZER).eval()
    context = torch.randint(0, 640, (3, 4, 40, 38))
    target = torch.randint(0, 640, (3, 40, 38))
    frames = tokenizer.decode(target.numpy())
    evaluate, images = _validation_scores(prior, tokenizer, (context, target, frames), torch.device("cpu"))
    evaluate()  # generates with the weights as they are, laying them out
    code = int(target[0, 0, 0])
    with torch.no_grad():
        prior.head[-1].bias.fill_(0.0)
        prior.head[-1].bias[code] = 1e4  # every position now predicts this code
    after = evaluate()
    everywhere = tokenizer.decode(np.full((3, 40, 38), code))
    assert after["val_next_pixel_acc"] == pytest.approx(frame_errors(frames, everywhere, "freeway")["pixel_acc"])
    assert images()["next_frame"].shape[0] > 0


def test_a_model_of_freeway_takes_no_caution_and_no_held_out_mode_trains_it(freeway_store):
    from dynplan.models.caution import Caution
    from dynplan.models.world_model import LearnedWorldModel

    tokenizer = VQVAE(TOKENIZER)
    prior = ConditionalPixelCNN(PRIOR.model_copy(update={"channels": 8, "layers": 2}))
    with pytest.raises(ValueError, match=r"caution \{'margin': 1\} reads the road's obstacle values; a model of the "
                                         "freeway world takes none"):  # fmt: skip
        LearnedWorldModel(tokenizer, prior, caution=Caution(margin=1))
    every = FrameDataset(freeway_store / "frames.zarr", "all")
    assert every.seeds[every.episodes].tolist() == [0, 5]  # mode 4 is held out of every split
