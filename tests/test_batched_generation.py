"""Batched generation (`dynplan.models.batched`): the compiled kernel's grids and occupancy over a whole batch, on
the device the world model is given, and the world model switching to it for large batches."""

import numpy as np
import pytest
import torch

from dynplan.models.batched import batched_weights, generate_batched
from dynplan.models.configs import PixelCNNConfig
from dynplan.models.generation import generate_fast
from dynplan.models.pixelcnn import ConditionalPixelCNN, draw_uniforms

SMALL = PixelCNNConfig(codebook_size=16, channels=8, layers=4, embed_dim=4, condition_channels=8)


def sharp_model(seed: int, K: int, first_kernel: int = 7) -> ConditionalPixelCNN:
    torch.manual_seed(seed)
    model = ConditionalPixelCNN(SMALL.model_copy(update={"codebook_size": K, "first_kernel": first_kernel})).eval()
    with torch.no_grad():
        for p in model.parameters():  # sharper distributions than at initialisation, so that choices vary
            p.mul_(3.0)
    return model


@pytest.mark.parametrize(("seed", "K", "grid", "batch", "first_kernel"),
                         [(0, 16, 6, 1, 7), (1, 64, 6, 9, 5), (2, 32, 12, 4, 3), (3, 16, 5, 17, 7)])  # fmt: skip
def test_batched_grids_equal_the_kernels_greedy_and_sampled(seed, K, grid, batch, first_kernel):
    model = sharp_model(seed, K, first_kernel)
    context = torch.randint(0, K, (batch, 4, grid, grid))
    greedy = generate_batched(model, context)
    assert torch.equal(greedy, generate_fast(model, context))
    assert len(greedy.unique()) > 1
    uniforms = draw_uniforms(batch, grid, grid, 1.0, torch.Generator().manual_seed(seed))
    sampled = generate_batched(model, context, 1.0, uniforms=uniforms)
    assert torch.equal(sampled, generate_fast(model, context, 1.0, uniforms=uniforms))
    assert not torch.equal(sampled, greedy)
    # drawing its own numbers, it draws them as the kernel does
    drawn = generate_batched(model, context, 1.0, generator=torch.Generator().manual_seed(seed))
    assert torch.equal(drawn, sampled)


def test_a_rows_grid_does_not_depend_on_the_rest_of_its_batch(monkeypatch):
    from dynplan.models import batched

    model = sharp_model(4, 32)
    context = torch.randint(0, 32, (12, 4, 6, 6))
    table = (torch.rand(32, 4, generator=torch.Generator().manual_seed(0)) < 0.4).float()
    together, expected = generate_batched(model, context, table=table)
    assert torch.equal(together[5:6], generate_batched(model, context[5:6]))
    assert torch.equal(together[:3], generate_batched(model, context[:3]))
    monkeypatch.setattr(batched, "BLOCK_ROWS", 5)  # 12 rows in blocks of 5, 5 and 2
    blocks, blocks_expected = generate_batched(model, context, table=table)
    assert torch.equal(blocks, together)
    np.testing.assert_allclose(blocks_expected.numpy(), expected.numpy(), atol=1e-6)


def test_batched_occupancy_is_the_kernels_softmax_against_the_table():
    model = sharp_model(5, 16)
    context = torch.randint(0, 16, (6, 4, 6, 6))
    table = (torch.rand(16, 4, generator=torch.Generator().manual_seed(0)) < 0.4).float()
    codes, expected = generate_batched(model, context, table=table)
    kernel_codes, kernel_expected = generate_fast(model, context, table=table.numpy())
    assert torch.equal(codes, kernel_codes) and expected.shape == (6, 6, 6, 4)
    np.testing.assert_allclose(expected.numpy(), kernel_expected, atol=1e-5)
    assert 0.05 < expected.mean() < 0.95  # not a trivial table


def test_weights_are_laid_out_once_and_stay_as_they_were_laid_out():
    model = sharp_model(6, 16)
    context = torch.randint(0, 16, (3, 4, 6, 6))
    kept = batched_weights(model)
    before = generate_batched(model, context, weights=kept)
    assert kept.device == torch.device("cpu")
    assert torch.equal(before, generate_batched(model, context))
    with torch.no_grad():
        model.head[3].bias.add_(torch.linspace(-5, 5, 16))  # a new head changes fresh layouts only
    assert torch.equal(generate_batched(model, context), generate_fast(model, context))
    assert not torch.equal(generate_batched(model, context), before)
    assert torch.equal(generate_batched(model, context, weights=kept), before)


def test_the_world_model_generates_large_batches_batched_and_names_a_bad_device(monkeypatch):
    from dynplan.models import chain, world_model
    from dynplan.models.configs import VQVAEConfig
    from dynplan.models.vqvae import VQVAE

    tokenizer = VQVAE(VQVAEConfig(channels=(8, 8), strides=(2, 2), latent_dim=4, codebook_size=16,
                                  likelihood="categorical", local=True)).eval()  # fmt: skip
    prior = sharp_model(7, 16)
    model = world_model.LearnedWorldModel(tokenizer, prior, device="cpu")
    h, w = tokenizer.config.grid
    context = torch.randint(0, 16, (3, 4, h, w))
    calls = []
    original = chain.generate_batched
    monkeypatch.setattr(chain, "generate_batched", lambda *a, **k: calls.append(1) or original(*a, **k))
    kernel, _ = chain.chain(prior, context, [2] * 3, model.chain_spec())
    assert not calls
    monkeypatch.setattr(chain, "BATCHED_FROM", 2)
    assert torch.equal(chain.chain(prior, context, [2] * 3, model.chain_spec())[0], kernel) and len(calls) == 2
    with pytest.raises(ValueError, match="device must be"):
        world_model.LearnedWorldModel(tokenizer, prior, device="gpu0")


@pytest.mark.parametrize("temperature", [0.3, 1.0, 2.5])
@pytest.mark.parametrize(("K", "scale"), [(16, 1.0), (512, 8.0), (4096, 30.0)])
def test_the_batched_pick_draws_pixelcnn_picks_codes(temperature, K, scale):
    """The batched inverse transform (float32 maximum, float64 work in place, buffers reused) draws the codes of
    `pixelcnn.pick`'s float64 rule, bit for bit, over logits from flat to peaked and uniforms from 0 to 1."""
    from dynplan.models.batched import _pick
    from dynplan.models.pixelcnn import pick

    g = torch.Generator().manual_seed(K)
    logits = torch.randn(64, K, generator=g) * scale
    logits[::7] = logits[::7].round()  # ties between codes
    uniforms = torch.rand(64, generator=g, dtype=torch.float64)
    uniforms[:2] = torch.tensor([0.0, 1.0 - 2**-53], dtype=torch.float64)
    work, cdf = torch.full((64, K), float("nan"), dtype=torch.float64), torch.empty(64, K, dtype=torch.float64)
    for _ in range(2):  # the second call finds the buffers holding the first call's numbers
        codes = _pick(logits, temperature, uniforms, work, cdf)
        assert torch.equal(codes, pick(logits, temperature, uniforms))
    assert len(codes.unique()) > 1


@pytest.mark.parametrize("temperature", [0.3, 1.0, 2.5])
@pytest.mark.parametrize(("K", "scale"), [(16, 1.0), (512, 8.0), (4096, 30.0)])
def test_the_kernels_draw_picks_pixelcnn_picks_codes(temperature, K, scale):
    """The compiled draw the kernel and the CPU's batched generation share (`draw_rows`: a vectorised float64
    exp within an ulp of libm's, four rows' sums at a time and a remainder row by row) draws `pixelcnn.pick`'s codes
    over logits from flat to peaked, with ties, and uniforms from 0 to 1."""
    import numpy as np

    from dynplan.models.generation import draw_rows
    from dynplan.models.pixelcnn import pick

    g = torch.Generator().manual_seed(K + 1)
    logits = torch.randn(67, K, generator=g) * scale  # 16 blocks of four rows and three alone
    logits[::7] = logits[::7].round()
    uniforms = torch.rand(67, generator=g, dtype=torch.float64)
    uniforms[:2] = torch.tensor([0.0, 1.0 - 2**-53], dtype=torch.float64)
    codes = np.full(67, -1, np.int64)
    draw_rows(logits.numpy(), temperature, uniforms.numpy(), np.full((4, K), np.nan), np.empty(K), codes)
    assert np.array_equal(codes, pick(logits, temperature, uniforms).numpy())
    assert len(np.unique(codes)) > 1
