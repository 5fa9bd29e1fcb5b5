"""The conditional gated PixelCNN: causality proven by gradients, conditioning, greedy generation."""

import pytest
import torch

from dynplan.bench.reference import generate_naive
from dynplan.config import ConfigError
from dynplan.models.configs import PixelCNNConfig
from dynplan.models.pixelcnn import ConditionalPixelCNN

SMALL = PixelCNNConfig(codebook_size=16, channels=8, layers=4, embed_dim=4, condition_channels=8)


@pytest.fixture(scope="module")
def model():
    torch.manual_seed(0)
    return ConditionalPixelCNN(SMALL)


@pytest.mark.parametrize("position", [(0, 0), (0, 4), (2, 3), (5, 5), (3, 0)])
def test_causality_no_gradient_from_the_position_or_later(model, position):
    i, j = position
    h = w = 6
    x = torch.randn(1, SMALL.channels, h, w, requires_grad=True)
    condition = model.condition(torch.randint(0, 16, (1, 4, h, w)))
    out = model.logits_from_embedding(x, condition)[0, :, i, j].sum()
    (grad,) = torch.autograd.grad(out, x)
    influence = grad.abs().sum(dim=(0, 1))  # (h, w)
    order = torch.arange(h * w).view(h, w)
    assert influence[order >= i * w + j].sum() == 0  # its own and every later position: exactly zero
    if i * w + j > 0:
        assert influence[order < i * w + j].sum() > 0  # and it does see what came before


def test_the_whole_receptive_field_above_is_seen(model):
    """No blind spot: the last position depends on every earlier one (4 layers with 7 and 3 kernels)."""
    x = torch.randn(1, SMALL.channels, 6, 6, requires_grad=True)
    condition = model.condition(torch.zeros(1, 4, 6, 6, dtype=torch.long))
    (grad,) = torch.autograd.grad(model.logits_from_embedding(x, condition)[0, :, 5, 5].sum(), x)
    influence = grad.abs().sum(dim=(0, 1)).flatten()
    assert (influence[:-1] > 0).all()


def test_conditioning_reaches_every_position(model):
    context = torch.randint(0, 16, (1, 4, 6, 6))
    codes = torch.randint(0, 16, (1, 6, 6))
    a = model.logits(codes, model.condition(context))
    b = model.logits(codes, model.condition((context + 1) % 16))
    assert ((a - b).abs().sum(dim=1) > 0).all()


def test_teacher_forced_loss_and_greedy_generation_are_consistent(model):
    context = torch.randint(0, 16, (3, 4, 6, 6))
    codes = generate_naive(model, context).clone()  # an ordinary tensor outside inference mode
    assert codes.shape == (3, 6, 6) and codes.dtype == torch.long
    logits = model.logits(codes, model.condition(context))
    assert torch.equal(logits.argmax(1), codes)  # each greedy choice is the argmax given the ones before it
    out = model(context, codes)
    assert out.accuracy == 1.0 and out.loss > 0
    sampled = generate_naive(model, context, temperature=1.0, generator=torch.Generator().manual_seed(1))
    again = generate_naive(model, context, temperature=1.0, generator=torch.Generator().manual_seed(1))
    assert torch.equal(sampled, again)


def test_training_loss_equals_the_cross_entropy_of_the_logits(model):
    """The loss takes the output layer a block of positions at a time (for speed): the same loss, accuracy and
    gradients as the plain cross-entropy of the logits."""
    import torch.nn.functional as F

    context, target = torch.randint(0, 16, (5, 4, 6, 6)), torch.randint(0, 16, (5, 6, 6))
    out = model(context, target)
    grads = torch.autograd.grad(out.loss, list(model.parameters()), allow_unused=True)
    logits = model.logits(target, model.condition(context))
    plain = F.cross_entropy(logits, target)
    expected = torch.autograd.grad(plain, list(model.parameters()), allow_unused=True)
    torch.testing.assert_close(out.loss, plain)
    assert out.accuracy == (logits.argmax(1) == target).float().mean()
    for got, want in zip(grads, expected, strict=True):
        assert (got is None) == (want is None)
        if got is not None:
            torch.testing.assert_close(got, want, rtol=1e-4, atol=1e-6)


@pytest.mark.parametrize("chunk", [1, 7, 180, 1000])
def test_the_blocked_head_loss_is_the_same_at_any_block_size(chunk):
    """Blocks of 1, an uneven 7, exactly the rows and more than the rows give the plain cross-entropy's loss,
    accuracy and gradients, also for a row whose target is not the most probable code."""
    import torch.nn.functional as F

    from dynplan.models.head_loss import head_cross_entropy

    torch.manual_seed(0)
    hidden = torch.randn(180, 8, requires_grad=True)
    weight, bias = torch.randn(33, 8, requires_grad=True), torch.randn(33, requires_grad=True)
    target = torch.randint(0, 33, (180,))
    loss, accuracy = head_cross_entropy(hidden, weight, bias, target, chunk)
    got = torch.autograd.grad(loss, (hidden, weight, bias))
    logits = hidden @ weight.T + bias
    plain = F.cross_entropy(logits, target)
    want = torch.autograd.grad(plain, (hidden, weight, bias))
    torch.testing.assert_close(loss, plain)
    assert 0 < accuracy < 1 and accuracy == (logits.argmax(1) == target).float().mean()
    for g, w in zip(got, want, strict=True):
        torch.testing.assert_close(g, w)


def test_codebook_init_keeps_the_codebook_geometry():
    """Embeddings started from the codebook: distances between codes are the codebook's, up to one scale."""
    torch.manual_seed(0)
    model = ConditionalPixelCNN(SMALL)  # channels 8 (wider than the codebook), embed_dim 4 (its width)
    codebook = torch.randn(16, 4) * 3.0 + 1.0
    model.embed_codebook(codebook)
    target = torch.cdist(codebook, codebook)
    for table in (model.embed.weight, model.context_embed.weight):
        distances = torch.cdist(table, table)
        torch.testing.assert_close(distances / distances.max(), target / target.max(), rtol=1e-4, atol=1e-5)
    with pytest.raises(ValueError, match="codebook has 8 entries"):
        model.embed_codebook(torch.randn(8, 4))


def test_config_errors():
    with pytest.raises(ConfigError, match="layers=1 is invalid"):
        PixelCNNConfig(layers=1)
    with pytest.raises(ValueError, match="kernel must be odd"):
        ConditionalPixelCNN(PixelCNNConfig(kernel=4))


def test_small_real_training_on_a_code_store_lowers_the_loss(tmp_path, recorded_logs):
    import numpy as np

    from dynplan.data.build import build_frame_store_from_logs
    from dynplan.data.store import list_logs
    from dynplan.models.checkpoint import load_pixelcnn_checkpoint
    from dynplan.models.configs import VQVAEConfig
    from dynplan.training.budget import TrainBudget
    from dynplan.training.codes import build_codes
    from dynplan.training.pixelcnn import train_pixelcnn
    from dynplan.training.vqvae import train_vqvae

    store = tmp_path / "frames.zarr"
    build_frame_store_from_logs(store, list_logs(recorded_logs))
    tokenizer = VQVAEConfig(name="tiny", channels=(8, 8, 8), strides=(2, 2, 2), latent_dim=4, codebook_size=16,
                            likelihood="categorical", local=True, codebook_fit="contents", batch_size=8)  # fmt: skip
    vq = train_vqvae(store, tmp_path / "vq", tokenizer, TrainBudget(epochs=2, steps_per_epoch=20, val_frames=50,
                                                                    threads=1))  # fmt: skip
    build_codes(store, vq, "tiny")
    config = SMALL.model_copy(update={"batch_size": 16, "learning_rate": 3e-3})
    path = train_pixelcnn(store, "codes_tiny", tmp_path / "prior", config,
                          TrainBudget(epochs=3, steps_per_epoch=25, val_frames=32, threads=1))  # fmt: skip
    history = torch.load(path, weights_only=False)["history"]
    assert history[-1]["loss"] < 0.8 * history[0]["loss"]
    assert history[-1]["val_loss"] < history[0]["val_loss"]
    assert {"val_next_fn_rate", "val_next_fp_rate", "val_next_goal_exact", "windows_seen"} <= set(history[-1])
    assert np.isfinite(history[-1]["val_loss"])
    model = load_pixelcnn_checkpoint(path)
    assert generate_naive(model, torch.zeros(1, 4, 6, 6, dtype=torch.long)).shape == (1, 6, 6)
    wrong_k = SMALL.model_copy(update={"codebook_size": 32})
    with pytest.raises(ValueError, match="holds codes of K=16"):
        train_pixelcnn(store, "codes_tiny", tmp_path / "other", wrong_k, TrainBudget(epochs=1, steps_per_epoch=1))
    assert history[-1]["learning_rate"] == pytest.approx(config.learning_rate)  # an epoch mean
    # A half-life of 4 batches: the rate of the first epoch's batches averages below the initial one, the next
    # epoch's (resumed from the checkpoint) lower still.
    decaying = config.model_copy(update={"learning_rate_halflife": 4 * 16})
    path = train_pixelcnn(store, "codes_tiny", tmp_path / "decaying", decaying,
                          TrainBudget(epochs=1, steps_per_epoch=4, val_frames=8, threads=1))  # fmt: skip
    path = train_pixelcnn(store, "codes_tiny", tmp_path / "decaying", decaying,
                          TrainBudget(epochs=2, steps_per_epoch=4, val_frames=8, threads=1))  # fmt: skip
    rates = [row["learning_rate"] for row in torch.load(path, weights_only=False)["history"]]
    assert config.learning_rate > rates[0] > rates[1] > config.learning_rate / 4
    # A snapshot of a run to commit as weights: the model without the optimiser's state.
    from dynplan.training.loop import export_weights

    exported = export_weights(tmp_path / "decaying" / "checkpoint.pt", tmp_path / "weights.pt", "pixelcnn")
    state = torch.load(exported, weights_only=False)
    assert "optimiser" not in state and state["epoch"] == 2
    snapshot = load_pixelcnn_checkpoint(exported).state_dict()
    assert all(torch.equal(v, load_pixelcnn_checkpoint(path).state_dict()[k]) for k, v in snapshot.items())


@pytest.mark.parametrize(("seed", "K", "grid", "batch"), [(0, 16, 6, 1), (1, 64, 6, 3), (2, 32, 12, 2), (3, 16, 5, 1)])
def test_fast_generation_equals_the_naive_reference(seed, K, grid, batch):
    from dynplan.models.generation import generate_fast

    torch.manual_seed(seed)
    model = ConditionalPixelCNN(SMALL.model_copy(update={"codebook_size": K})).eval()
    for p in model.parameters():  # sharper distributions than at initialisation, so that choices vary
        p.data.mul_(3.0)
    context = torch.randint(0, K, (batch, 4, grid, grid))
    greedy = generate_fast(model, context)
    assert torch.equal(greedy, generate_naive(model, context))
    assert len(greedy.unique()) > 1
    fast = generate_fast(model, context, temperature=1.0, generator=torch.Generator().manual_seed(seed))
    naive = generate_naive(model, context, temperature=1.0, generator=torch.Generator().manual_seed(seed))
    assert torch.equal(fast, naive)


def test_the_kernels_weights_are_named_as_the_kernel_takes_them_and_follow_the_model():
    import inspect

    from dynplan.models.generation import KernelWeights, _generate_grid, generate_fast, kernel_weights

    params = list(inspect.signature(_generate_grid.py_func).parameters)
    assert params == ["cond_v", "cond_h", "temperature", "uniforms", "table", "expected", "codes", "weights"]
    assert isinstance(kernel_weights(ConditionalPixelCNN(SMALL)), KernelWeights)  # read by name: one structure
    torch.manual_seed(0)
    model = ConditionalPixelCNN(SMALL.model_copy(update={"codebook_size": 16})).eval()
    context = torch.randint(0, 16, (2, 4, 6, 6))
    kept = kernel_weights(model)
    assert torch.equal(generate_fast(model, context, weights=kept), generate_fast(model, context))
    with torch.no_grad():
        for p in model.parameters():
            p.mul_(3.0)
    assert torch.equal(generate_fast(model, context), generate_naive(model, context))  # laid out anew each call


def test_learning_rate_halves_every_halflife_and_is_constant_without_one():
    from dynplan.training.pixelcnn import learning_rate

    decaying = SMALL.model_copy(update={"learning_rate": 1e-3, "batch_size": 64, "learning_rate_halflife": 640})
    assert learning_rate(decaying, 0) == pytest.approx(1e-3)
    assert learning_rate(decaying, 10) == pytest.approx(5e-4)  # 10 steps × 64 windows = one half-life
    assert learning_rate(decaying, 30) == pytest.approx(1.25e-4)
    assert learning_rate(SMALL, 10_000) == SMALL.learning_rate
    assert "learning_rate_halflife" not in SMALL.model_dump()  # unset, it leaves existing run keys as they were
    with pytest.raises(ConfigError, match="learning_rate_halflife=0 is invalid"):
        PixelCNNConfig(learning_rate_halflife=0)


def test_sampling_by_inverse_transform_follows_the_softmax():
    from dynplan.models.pixelcnn import draw_uniforms, pick

    logits = torch.tensor([[2.0, 0.0, -1.0, 1.0]]).expand(20_000, -1)
    uniforms = draw_uniforms(20_000, 1, 1, 1.0, torch.Generator().manual_seed(0))[:, 0, 0]
    counts = torch.bincount(pick(logits, 1.0, uniforms), minlength=4).double() / 20_000
    assert torch.allclose(counts, torch.softmax(logits[0].double(), 0), atol=0.01)
    hot = torch.bincount(pick(logits, 0.25, uniforms), minlength=4).double() / 20_000  # colder: nearer the argmax
    assert hot[0] > 0.97
    with pytest.raises(ValueError, match="temperature must be >= 0"):
        draw_uniforms(1, 1, 1, -1.0, None)


def test_prior_curves_plot_and_name_a_bad_run_argument(tmp_path, capsys):
    from lab import prior_curves

    header = "epoch,windows_seen,elapsed_s,val_accuracy,val_next_fn_rate\n"
    (tmp_path / "a.csv").write_text(header + "1,3200,60,0.05,0.9\n2,6400,120,0.1,0.5\n")
    (tmp_path / "empty.csv").write_text(header)
    prior_curves.main([f"a={tmp_path / 'a.csv'}", "--plot", str(tmp_path / "c.png")])
    assert (tmp_path / "c.png").stat().st_size > 1000
    assert prior_curves.read_metrics(tmp_path / "a.csv")["val_accuracy"] == [0.05, 0.1]
    with pytest.raises(ValueError, match="empty.csv: no epochs recorded"):
        prior_curves.read_metrics(tmp_path / "empty.csv")
    with pytest.raises(SystemExit):
        prior_curves.main([str(tmp_path / "a.csv"), "--plot", str(tmp_path / "d.png")])
    assert "is not NAME=METRICS_CSV" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        prior_curves.main([f"a={tmp_path / 'a.csv'}@many", "--plot", str(tmp_path / "d.png")])
    assert "WINDOWS a whole number" in capsys.readouterr().err


def test_prior_curves_place_a_continued_run_after_the_windows_its_start_had_seen(tmp_path, monkeypatch):
    from lab import prior_curves

    header = "epoch,windows_seen,elapsed_s,val_accuracy,val_next_fn_rate\n"
    (tmp_path / "a.csv").write_text(header + "1,3200,60,0.05,0.9\n")
    plotted = []
    import matplotlib.axes

    real_plot = matplotlib.axes.Axes.plot

    def plot(self, x, *args, **kwargs):
        plotted.append(list(x))
        return real_plot(self, x, *args, **kwargs)

    monkeypatch.setattr(matplotlib.axes.Axes, "plot", plot)
    runs = [f"start={tmp_path / 'a.csv'}", f"on={tmp_path / 'a.csv'}@576000"]
    prior_curves.main([*runs, "--plot", str(tmp_path / "c.png")])
    assert [3.2] in plotted and [579.2] in plotted  # thousands of windows: its own, and after the start's 576,000


def test_the_kernels_exp_and_gate_match_libm():
    import numpy as np

    from dynplan.models.generation import _exp_inplace, _gate

    x = np.linspace(-87.0, 0.0, 200_001).astype(np.float32)
    exact = np.exp(x.astype(np.float64))
    out = x.copy()
    total = _exp_inplace(out, np.zeros(len(x), np.int32))
    assert np.max(np.abs(out - exact) / exact) < 3e-7
    assert total == pytest.approx(exact.sum(), rel=1e-5)
    pre = np.random.default_rng(0).normal(0.0, 4.0, 64).astype(np.float32)
    pre[:4] = [0.0, -0.0, 1e-8, 30.0]
    gated = np.zeros(32, np.float32)
    _gate(pre, gated, np.zeros(64, np.float32), np.zeros(64, np.int32))
    want = np.tanh(pre[:32].astype(np.float64)) / (1.0 + np.exp(-pre[32:].astype(np.float64)))
    assert np.max(np.abs(gated - want)) < 2e-7


def test_the_kernels_float64_exp_is_within_an_ulp_of_numpys():
    import numpy as np

    from dynplan.models.generation import _exp64_inplace

    x = -np.linspace(0.0, 708.0, 1_000_001)
    x[1] = -1e-300
    out = x.copy()
    _exp64_inplace(out, np.empty(len(x)))
    exact = np.exp(x)
    assert np.max(np.abs(out - exact) / np.spacing(exact)) <= 1.0
    tiny = np.array([-708.0, -708.5, -745.0, -1e4])
    _exp64_inplace(tiny, np.empty(4))
    assert np.all(tiny == tiny[0]) and abs(tiny[0] - np.exp(-708.0)) <= np.spacing(np.exp(-708.0))  # flushed to e^-708


def test_the_kernels_row_blocks_give_each_row_its_grid_alone():
    from dynplan.models.generation import generate_fast

    torch.manual_seed(5)
    model = ConditionalPixelCNN(SMALL.model_copy(update={"codebook_size": 32})).eval()
    context = torch.randint(0, 32, (5, 4, 6, 6))
    threads = torch.get_num_threads()
    try:
        torch.set_num_threads(2)  # two blocks of rows on the kernel's threads
        together = generate_fast(model, context, temperature=1.0, generator=torch.Generator().manual_seed(1))
        torch.set_num_threads(1)
        alone = generate_fast(model, context, temperature=1.0, generator=torch.Generator().manual_seed(1))
    finally:
        torch.set_num_threads(threads)
    assert torch.equal(together, alone)
    assert all(torch.equal(generate_fast(model, context[i : i + 1]), generate_fast(model, context)[i : i + 1])
               for i in range(5))  # fmt: skip
