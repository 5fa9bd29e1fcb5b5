"""The VQ-VAE: shapes and round trips, likelihoods, quantizer, and small real trainings (resume, cache, errors)."""

import re

import numpy as np
import pytest
import torch

from dynplan.config import ConfigError
from dynplan.data.build import build_frame_store_from_logs
from dynplan.data.datasets import FrameDataset
from dynplan.data.patches import distinct_patches
from dynplan.data.store import list_logs
from dynplan.env import RoadConfig, generate_world
from dynplan.models.checkpoint import CheckpointError, load_vqvae_checkpoint
from dynplan.models.configs import PRESETS, VQVAEConfig
from dynplan.models.likelihood import WORLD_VALUES, Categorical, DMoL, snap, snap_tensor, to_unit, value_index
from dynplan.models.vqvae import DECODE_ROWS, SHARPNESS_GRID, VQVAE
from dynplan.training.budget import TrainBudget
from dynplan.training.vqvae import content_sample, train_vqvae

TINY = VQVAEConfig(name="tiny", channels=(8, 8, 8), strides=(2, 2, 2), latent_dim=4, codebook_size=16, n_mixtures=3,
                   batch_size=8)  # fmt: skip


@pytest.fixture(scope="module")
def frames():
    return torch.from_numpy(generate_world(RoadConfig(), 4).frames[:16].copy())


@pytest.fixture(scope="module")
def store(tmp_path_factory, recorded_logs):
    path = tmp_path_factory.mktemp("vq") / "frames.zarr"
    build_frame_store_from_logs(path, list_logs(recorded_logs))
    return path


@pytest.mark.parametrize("name", ["paper", "default"])
def test_presets_shapes_and_round_trip_types(name, frames):
    model = VQVAE(PRESETS[name]).eval()
    codes = model.encode(frames)
    assert codes.shape == (16, *PRESETS[name].grid) and codes.dtype == torch.int64
    assert int(codes.max()) < PRESETS[name].codebook_size
    decoded = model.decode(codes)
    assert decoded.shape == (16, 48, 48) and decoded.dtype == torch.uint8
    assert set(decoded.unique().tolist()) <= set(WORLD_VALUES)
    samples = model.decode_samples(codes[:2], 3, torch.Generator().manual_seed(0))
    assert samples.shape == (3, 2, 48, 48)
    assert PRESETS["paper"].grid == (6, 6) and PRESETS["paper"].codebook_size == 512


def test_paper_encoder_is_four_4x4_convolutions_42_32_16_16():
    convs = [m for m in VQVAE(PRESETS["paper"]).encoder.modules() if isinstance(m, torch.nn.Conv2d)]
    assert [(c.out_channels, c.kernel_size, c.stride) for c in convs] == [
        (42, (4, 4), (2, 2)), (32, (4, 4), (2, 2)), (16, (4, 4), (2, 2)), (16, (4, 4), (1, 1))]  # fmt: skip


def test_patch_local_codes_see_and_decode_only_their_own_patch(frames):
    config = VQVAEConfig(**PRESETS["default"].model_copy(update={"local": True, "codebook_size": 64}).model_dump())
    model = VQVAE(config).eval()
    x = frames[:1].clone()
    changed = x.clone()
    changed[0, 5, 9] = 244 if int(x[0, 5, 9]) != 244 else 0  # a pixel of the patch at code (1, 2)
    with torch.no_grad():
        z, z_changed = (model.encoder(to_unit(f).unsqueeze(1)) for f in (x, changed))
        moved = (z - z_changed).abs().sum(1)[0] > 0
        assert moved.nonzero().tolist() == [[1, 2]]
        codes = model.encode(x)
        other = codes.clone()
        other[0, 4, 7] = (codes[0, 4, 7] + 1) % 64
        differs = (model.decode_params(codes) - model.decode_params(other)).abs().sum(1)[0] > 0
    rows, cols = differs.nonzero().T.tolist()
    assert set(rows) <= set(range(16, 20)) and set(cols) <= set(range(28, 32)) and rows


def test_patch_local_encoding_of_distinct_patches_equals_encoding_whole_frames(frames):
    config = VQVAEConfig(**PRESETS["default"].model_copy(update={"local": True, "codebook_size": 64}).model_dump())
    torch.manual_seed(0)  # an untrained model's codes: the same whatever ran before in this process
    model = VQVAE(config).eval()
    whole = model.quantizer.nearest(model.encoder(to_unit(frames).unsqueeze(1)))
    assert (model.encode(frames) == whole).all() and len(whole.unique()) > 1


def test_a_checkpoint_recording_settings_this_code_lacks_loads_when_its_weights_fit(frames, tmp_path):
    """A checkpoint records its trainer's whole config: training-only settings the code no longer has (an EMA
    codebook's) are left out with the codebook's running statistics; weights of another architecture are refused."""
    from dynplan.models.checkpoint import VQVAE_KIND, save

    model = VQVAE(TINY).eval()
    old = {**TINY.model_dump(), "ema": True, "restart_dead": True, "n_codebooks": 1, "obstacle_weight": 1.0}
    weights = {**model.state_dict(), "quantizer.embed": model.quantizer.embed.detach()[None],
               "quantizer.cluster_size": torch.ones(1, 16), "quantizer.embed_sum": torch.zeros(1, 16, 4)}  # fmt: skip
    loaded = VQVAE.from_checkpoint(old, weights).eval()
    assert torch.equal(loaded.encode(frames), model.encode(frames))
    assert torch.equal(loaded.decode(model.encode(frames)), model.decode(model.encode(frames)))
    three = {**weights, "quantizer.embed": torch.zeros(3, 16, 4)}  # several codebooks per position
    save(tmp_path / "vqvae.pt", {"kind": VQVAE_KIND, "config": {**old, "n_codebooks": 3}, "model": three})
    with pytest.raises(CheckpointError, match=r"vqvae.pt: tensor 'quantizer.embed' has shape \(3, 16, 4\) but "
                       r"configuration 'tiny' needs \(16, 4\)$"):  # fmt: skip
        load_vqvae_checkpoint(tmp_path / "vqvae.pt")


def test_likelihoods_score_the_truth_best():
    frames = torch.tensor([[[0, 45, 85], [100, 130, 244]]], dtype=torch.uint8)
    assert torch.equal(snap(to_unit(frames)), frames)
    assert value_index(frames).tolist() == [[[0, 1, 2], [3, 4, 6]]]
    dmol = DMoL(n_mix=2)
    params = torch.zeros(1, 6, 2, 3)
    params[:, 2:4] = to_unit(frames).unsqueeze(1)  # both components centred on the truth
    params[:, 4:6] = -5.0  # sharp
    wrong = params.clone()
    wrong[:, 2:4] = -wrong[:, 2:4]
    assert dmol.nll(params, frames).mean() < dmol.nll(wrong, frames).mean()
    assert torch.equal(dmol.mid(params), frames)
    logits = torch.nn.functional.one_hot(value_index(frames), 7).permute(0, 3, 1, 2).float() * 10
    assert torch.equal(Categorical().mid(logits), frames)


def test_compiled_snap_and_mid_point_equal_their_tensor_formulas():
    """`snap` and `DMoL.mid` run as one compiled pass on the CPU: the same float32 arithmetic as the tensor formulas
    (nearest world value of (u + 1) · 127.5, the first of two equally near; the first most probable component)."""
    values = torch.tensor(WORLD_VALUES, dtype=torch.float32)
    unit = torch.rand(200_000, generator=torch.Generator().manual_seed(0)) * 2.2 - 1.1
    edges = (values[1:] + values[:-1]) / 2 / 127.5 - 1.0  # half-way between two values, and the floats beside it
    unit[: 3 * len(edges)] = torch.cat(
        [edges, torch.nextafter(edges, values[-1:]), torch.nextafter(edges, -values[-1:])]
    )
    assert torch.equal(snap(unit.reshape(400, 500)), snap_tensor(unit).reshape(400, 500))
    dmol = DMoL(n_mix=4)
    params = torch.randn(6, 12, 5, 7, generator=torch.Generator().manual_seed(1))
    params[:, :4] = params[:, :4].round()  # ties between components: the first wins
    logit_pi, mu = params[:, :4], params[:, 4:8]
    want = snap_tensor(mu.gather(1, logit_pi.argmax(1, keepdim=True)).squeeze(1).clamp(-1.0, 1.0))
    assert torch.equal(dmol.mid(params), want) and torch.equal(dmol.mid(params[:, :8]), want)
    assert torch.equal(dmol.mid_tensor(params), want)


def test_decoding_in_blocks_and_only_the_mid_points_channels_gives_the_whole_decoders_numbers():
    """On one thread, as the world model decodes (`world_model.one_thread`: on two, a convolution over an odd batch
    splits its sums otherwise), a frame's numbers do not depend on the frames decoded with it."""
    from dynplan.models.world_model import one_thread

    model = VQVAE(PRESETS["paper"]).eval()
    codes = torch.randint(
        0, PRESETS["paper"].codebook_size, (DECODE_ROWS * 2 + 3, 6, 6), generator=torch.Generator().manual_seed(2)
    )
    with torch.inference_mode(), one_thread():
        whole = model.decoder(model.quantizer.lookup(codes))
        assert torch.equal(model.decode_params(codes), whole)
        ones = torch.cat([model.decoder(model.quantizer.lookup(codes[i : i + 1])) for i in range(7)])
        assert torch.equal(ones, whole[:7])
        assert torch.equal(model.decode_params(codes, model.pixel.mid_channels), whole[:, : model.pixel.mid_channels])
        assert torch.equal(torch.from_numpy(model.decode(codes.numpy())), model.pixel.mid(whole))


@pytest.mark.parametrize("likelihood", [Categorical(), DMoL(n_mix=3)])
def test_decoder_samples_follow_the_likelihood_and_many_at_once_are_many_one_at_a_time(likelihood):
    torch.manual_seed(0)
    params = torch.randn(2, likelihood.channels, 3, 4) * 2
    if isinstance(likelihood, Categorical):  # the frequencies of 4,000 samples against the softmax
        drawn = likelihood.sample_with(params, likelihood.noise(params.shape, 4000, torch.Generator().manual_seed(1)))
        counts = torch.stack([(drawn == v).float().mean(0) for v in WORLD_VALUES], dim=1)  # (2, 7, 3, 4)
        assert (counts - torch.softmax(params, dim=1)).abs().max() < 0.035
    many = likelihood.sample_with(params, likelihood.noise(params.shape, 5, torch.Generator().manual_seed(2)))
    generator = torch.Generator().manual_seed(2)
    assert torch.equal(many, torch.stack([likelihood.sample(params, generator) for _ in range(5)]))
    assert many.shape == (5, 2, 3, 4) and len(many.unique()) > 1
    assert set(many.unique().tolist()) <= set(WORLD_VALUES)


@pytest.mark.parametrize(("frames", "samples", "size"), [(3, 5, (5, 7)), (7, 10, (48, 48)), (1, 1, (1, 1))])
def test_decoder_samples_in_blocks_are_the_whole_batchs_numbers(frames, samples, size):
    """`DMoL.sample_with` draws `SAMPLE_ROWS` (sample, frame) pairs at a time, in place; `sample_tensor` the whole
    batch at once: the same numbers, whatever the shape (odd sizes leave a block's last elements to scalar code)."""
    likelihood, generator = DMoL(n_mix=10), torch.Generator().manual_seed(frames)
    params = torch.randn(frames, likelihood.channels, *size, generator=generator) * 3
    noise = likelihood.noise(params.shape, samples, generator)
    assert torch.equal(likelihood.sample_with(params, noise), likelihood.sample_tensor(params, noise))


def test_config_errors():
    with pytest.raises(ConfigError, match="strides must each be 1 or 2"):
        VQVAEConfig(strides=(2, 3, 2, 1))
    with pytest.raises(ConfigError, match="codebook_size=1 is invalid"):
        VQVAEConfig(codebook_size=1)
    with pytest.raises(ConfigError, match="unknown key 'ema'"):
        VQVAEConfig(ema=True)
    with pytest.raises(ConfigError, match="not divisible"):
        VQVAEConfig(height=50)


def test_small_real_training_lowers_the_loss(tmp_path, store):
    budget = TrainBudget(epochs=4, steps_per_epoch=25, val_frames=200, threads=1)
    config = TINY.model_copy(update={"likelihood": "categorical"})
    path = train_vqvae(store, tmp_path, VQVAEConfig(**config.model_dump()), budget)
    assert path.name == "vqvae.pt"
    history = torch.load(path, weights_only=False)["history"]
    assert len(history) == 4
    assert history[-1]["reconstruction"] < 0.7 * history[0]["reconstruction"]
    assert (tmp_path / "metrics.csv").read_text().count("\n") == 5
    assert (tmp_path / "reconstructions.png").stat().st_size > 1000
    model = load_vqvae_checkpoint(path)
    assert model.encode(torch.zeros(2, 48, 48, dtype=torch.uint8)).shape == (2, 6, 6)


def test_training_resumes_after_an_interruption(tmp_path, store):
    budget = TrainBudget(epochs=3, steps_per_epoch=5, val_frames=50, threads=1)

    def interrupt(row):
        if row["epoch"] == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train_vqvae(store, tmp_path, TINY, budget, on_epoch=interrupt)
    assert not (tmp_path / "vqvae.pt").exists()
    epochs_seen = []
    train_vqvae(store, tmp_path, TINY, budget, on_epoch=lambda row: epochs_seen.append(row["epoch"]))
    assert epochs_seen == [3]  # epochs 1 and 2 were not redone
    history = torch.load(tmp_path / "vqvae.pt", weights_only=False)["history"]
    assert [row["epoch"] for row in history] == [1, 2, 3]


def test_a_truncated_final_checkpoint_is_exported_again_from_the_latest(tmp_path, store):
    budget = TrainBudget(epochs=2, steps_per_epoch=3, val_frames=20, threads=1)
    final = train_vqvae(store, tmp_path, TINY, budget)
    intact = torch.load(final, weights_only=False)
    final.write_bytes(final.read_bytes()[:4000])
    with pytest.warns(UserWarning, match="vqvae.pt: not a readable checkpoint .*; exported it again from"):
        again = train_vqvae(store, tmp_path, TINY, budget)
    restored = torch.load(again, weights_only=False)
    assert restored["epoch"] == 2 and restored["history"] == intact["history"]
    assert all(torch.equal(restored["model"][k], v) for k, v in intact["model"].items())
    (tmp_path / "checkpoint.pt").unlink()
    final.write_bytes(b"damaged")
    with pytest.raises(CheckpointError, match="vqvae.pt: not a readable checkpoint"):
        train_vqvae(store, tmp_path, TINY, budget)  # nothing to export it from: an error, not a silent retrain


def test_a_start_that_fails_leaves_no_run_folder(tmp_path, store):
    budget = TrainBudget(epochs=1, steps_per_epoch=2, val_frames=20, threads=1, init_from=str(tmp_path / "none.pt"))
    with pytest.raises(CheckpointError, match="none.pt: no such checkpoint"):
        train_vqvae(store, tmp_path / "run", TINY, budget)
    assert not (tmp_path / "run").exists()


def test_a_checkpoint_of_another_config_is_refused(tmp_path, store):
    budget = TrainBudget(epochs=1, steps_per_epoch=2, val_frames=20, threads=1)
    path = train_vqvae(store, tmp_path, TINY, budget)
    other = VQVAEConfig(**TINY.model_copy(update={"codebook_size": 32}).model_dump())
    with pytest.raises(CheckpointError, match=r"different configuration \(differs in codebook_size\)"):
        train_vqvae(store, tmp_path, other, budget)
    with pytest.raises(CheckpointError, match="differs in codebook_size"):
        load_vqvae_checkpoint(path, other)
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(CheckpointError, match="junk.pt: not a readable checkpoint"):
        load_vqvae_checkpoint(tmp_path / "junk.pt")


def test_train_flow_is_cached_across_runs(tmp_path, store, prefect_api):
    from flows.training import train_vqvae_flow

    budget = {"epochs": 1, "steps_per_epoch": 3, "val_frames": 20, "threads": 1}
    overrides = {k: v for k, v in TINY.model_dump().items() if k != "name"}
    first = train_vqvae_flow(store=str(store), model="paper", out=str(tmp_path), budget=budget, overrides=overrides)
    stamp = np.array([p.stat().st_mtime_ns for p in sorted(tmp_path.rglob("*")) if p.is_file()])
    second = train_vqvae_flow(store=str(store), model="paper", out=str(tmp_path), budget=budget, overrides=overrides)
    assert first == second
    assert (np.array([p.stat().st_mtime_ns for p in sorted(tmp_path.rglob("*")) if p.is_file()]) == stamp).all()


def test_codes_store_matches_the_encoder_and_is_incremental(tmp_path, store, recorded_logs):
    import shutil

    import xarray as xr
    import zarr

    from dynplan.data.datasets import WindowDataset
    from dynplan.training.codes import build_codes

    local = tmp_path / "frames.zarr"
    shutil.copytree(store, local)
    path = train_vqvae(
        local, tmp_path / "run", TINY, TrainBudget(epochs=1, steps_per_epoch=3, val_frames=20, threads=1)
    )
    assert build_codes(local, path, "tiny") == "codes_tiny"
    group = zarr.open_group(str(local), mode="r")
    codes = group["codes_tiny"]
    assert codes.shape == (6, 407, 6, 6) and codes.dtype == np.uint16 and codes.chunks == (1, 407, 6, 6)
    model = load_vqvae_checkpoint(path)
    np.testing.assert_array_equal(codes[3], model.encode(torch.from_numpy(group["frames"][3])).numpy())
    assert codes.attrs["checkpoint"] == str(path.resolve()) and len(codes.attrs["checkpoint_sha256"]) == 64
    stamp = {p: p.stat().st_mtime_ns for p in (local / "codes_tiny").rglob("c/*")}
    build_codes(local, path, "tiny")
    assert {p: p.stat().st_mtime_ns for p in (local / "codes_tiny").rglob("c/*")} == stamp  # nothing re-encoded
    assert xr.open_zarr(local)["codes_tiny"].dims == ("episode", "time", "code_y", "code_x")
    context, target = WindowDataset(local, "all", array="codes_tiny")[0]
    assert context.shape == (4, 6, 6) and target.shape == (6, 6)

    # A damaged code chunk is found, its encoding marked undone, and the next encoding redoes it.
    from dynplan.data.verify import verify_store

    encoded = codes[:]
    chunk = local / "codes_tiny" / "c" / "4" / "0" / "0" / "0"
    data = bytearray(chunk.read_bytes())
    data[len(data) // 2] ^= 0x40
    chunk.write_bytes(bytes(data))
    (damage,) = verify_store(local).damage
    assert (damage.array, damage.chunk, damage.repaired) == ("codes_tiny", "c/4/0/0/0", True)
    assert "marked undone from episode 4" in damage.describe()
    assert verify_store(local).damage == []  # nothing left that counts as encoded is damaged
    build_codes(local, path, "tiny")
    np.testing.assert_array_equal(zarr.open_group(str(local), mode="r")["codes_tiny"][:], encoded)
    assert zarr.open_group(str(local), mode="r")["codes_tiny"].attrs["episodes"] == 6


def test_load_vqvae_names_what_is_missing(tmp_path, store):
    from dynplan.models import load_vqvae, pretrained_path

    if not pretrained_path("vqvae", "paper").exists():
        with pytest.raises(CheckpointError, match="no pretrained VQ-VAE 'paper'.*python -m flows.train vqvae"):
            load_vqvae(model="paper")
    with pytest.raises(ValueError, match="model must be one of"):
        load_vqvae(model="huge")
    path = train_vqvae(store, tmp_path, TINY, TrainBudget(epochs=1, steps_per_epoch=2, val_frames=20, threads=1))
    model = load_vqvae(path)
    assert model.decode(model.encode(torch.zeros(1, 48, 48, dtype=torch.uint8))).shape == (1, 48, 48)


def test_a_run_can_start_from_another_runs_weights(tmp_path, store):
    budget = TrainBudget(epochs=1, steps_per_epoch=3, val_frames=20, threads=1)
    source = train_vqvae(store, tmp_path / "a", TINY, budget)
    tuned = VQVAEConfig(**TINY.model_copy(update={"goal_weight": 10.0, "learning_rate": 1e-9}).model_dump())
    warm = TrainBudget(**{**budget.model_dump(), "init_from": str(source)})
    path = train_vqvae(store, tmp_path / "b", tuned, warm)
    before, after = torch.load(source, weights_only=False), torch.load(path, weights_only=False)
    assert after["init_from"] == str(source)
    for name, value in before["model"].items():  # a vanishing learning rate: still the source's weights
        if value.is_floating_point():
            torch.testing.assert_close(after["model"][name], value, atol=1e-5, rtol=0)
    grown = VQVAEConfig(**TINY.model_copy(update={"codebook_size": 32, "learning_rate": 1e-9}).model_dump())
    bigger = torch.load(train_vqvae(store, tmp_path / "c", grown, warm), weights_only=False)["model"]
    assert bigger["quantizer.embed"].shape[0] == 32  # the old 16 codes first, then fresh ones
    torch.testing.assert_close(bigger["encoder.0.weight"], before["model"]["encoder.0.weight"], atol=1e-5, rtol=0)
    other = VQVAEConfig(**TINY.model_copy(update={"channels": (8, 8, 4)}).model_dump())
    with pytest.raises(CheckpointError, match=r"vqvae.pt: cannot start this run from it: the architecture differs"):
        train_vqvae(store, tmp_path / "d", other, warm)


def test_fields_added_later_keep_earlier_configs_keys():
    """Checkpoints and run folders are keyed by the config's dict: a field left at its neutral value is not in it."""
    from dynplan.config import digest

    assert "goal_weight" not in PRESETS["paper"].model_dump()
    assert PRESETS["default"].model_dump()["goal_weight"] == 10.0
    assert digest(PRESETS["paper"].model_dump())[:12] == "87cbbcbfe6de"  # its key without goal_weight
    assert "init_from" not in TrainBudget().model_dump()


def test_the_training_device_is_validated_and_names_no_new_run(store):
    from dynplan.training.runs import vqvae_run_dir

    with pytest.raises(ConfigError, match=r"device.*unknown torch device 'warp-drive'"):
        TrainBudget(device="warp-drive")
    assert "device" not in TrainBudget().model_dump()  # neutral: existing run keys hold
    config, budget = TINY.model_dump(), TrainBudget(epochs=2).model_dump()
    elsewhere = TrainBudget(epochs=9, threads=1, max_minutes=5, device="cpu").model_dump()
    assert vqvae_run_dir(store, "runs", config, budget) == vqvae_run_dir(store, "runs", config, elsewhere)


def test_checkpoints_hold_cpu_tensors_whatever_the_device(tmp_path, store):
    budget = TrainBudget(epochs=1, steps_per_epoch=2, val_frames=8, threads=1, device="cpu")
    train_vqvae(store, tmp_path, TINY, budget)
    state = torch.load(tmp_path / "checkpoint.pt", weights_only=False)
    tensors = [v for v in state["model"].values()] + [
        t for s in state["optimiser"]["state"].values() for t in s.values() if isinstance(t, torch.Tensor)
    ]
    assert tensors and all(t.device.type == "cpu" for t in tensors)


@pytest.mark.parametrize(
    ("model", "grid", "max_fn", "min_goals"), [("default", 12, 0.01, 0.95), ("paper", 6, 0.35, 0.3)]
)
def test_committed_weights_reconstruct_held_out_frames(model, grid, max_fn, min_goals):
    from dynplan.evaluation.cases import EVAL_SEED_START
    from dynplan.models import load_vqvae
    from dynplan.models.metrics import frame_errors

    tokenizer = load_vqvae(model=model)
    frames = generate_world(RoadConfig(agent_speed=0.5), EVAL_SEED_START + 1).frames[:200]
    codes = tokenizer.encode(torch.from_numpy(frames))
    assert codes.shape == (200, grid, grid)
    errors = frame_errors(frames, tokenizer.decode(codes).numpy())
    assert errors["fn_rate"] < max_fn and errors["goal_exact"] >= min_goals, errors


def test_an_interrupted_encoding_resumes_after_its_last_batch(tmp_path, store, monkeypatch):
    import shutil

    import dask.array as da
    import zarr

    from dynplan.training import codes as codes_module

    local = tmp_path / "frames.zarr"
    shutil.copytree(store, local)
    path = train_vqvae(
        local, tmp_path / "run", TINY, TrainBudget(epochs=1, steps_per_epoch=2, val_frames=20, threads=1)
    )
    real_store, calls = da.store, []

    def store_twice_then_fail(*args, **kwargs):
        calls.append(kwargs["regions"][0])
        if len(calls) > 2:
            raise KeyboardInterrupt
        return real_store(*args, **kwargs)

    monkeypatch.setattr(codes_module.da, "store", store_twice_then_fail)
    with pytest.raises(KeyboardInterrupt):
        codes_module.build_codes(local, path, "tiny", batch=2)
    partial = zarr.open_group(str(local), mode="r", use_consolidated=False)["codes_tiny"]
    assert partial.attrs["episodes"] == 4  # two batches of 2 kept
    consolidated = zarr.open_group(str(local), mode="r")["codes_tiny"]  # zarr's default view sees it too
    assert consolidated.attrs["episodes"] == 4
    from dynplan.data.datasets import WindowDataset

    assert WindowDataset(local, "all", array="codes_tiny").episodes.tolist() == [0, 1, 2, 3]  # only what is encoded
    encoded = []
    monkeypatch.setattr(
        codes_module.da, "store", lambda *a, **k: encoded.append(k["regions"][0]) or real_store(*a, **k)
    )
    codes_module.build_codes(local, path, "tiny", batch=2)
    assert encoded == [slice(4, 6)]  # only the batch that was interrupted
    group = zarr.open_group(str(local), mode="r")
    model = load_vqvae_checkpoint(path)
    for e in (1, 5):
        np.testing.assert_array_equal(
            group["codes_tiny"][e], model.encode(torch.from_numpy(group["frames"][e])).numpy()
        )


def test_train_command_line_names_a_missing_code_array(store, capsys):
    from flows.train import main

    with pytest.raises(SystemExit):
        main(["pixelcnn", "--store", str(store), "--codes", "codes_nope"])
    assert f"{store}: no codes_nope; train the VQ-VAE first" in capsys.readouterr().err


def test_code_statistics_tell_a_patch_local_code_from_a_context_dependent_one(tmp_path, capsys):
    import zarr

    from lab.codes import code_statistics, main, patch_keys

    frames = np.asarray(generate_world(RoadConfig(), 2).frames[:40])[None]  # (1, 40, 48, 48)
    keys, empty = patch_keys(frames[0], (12, 12))
    assert empty.mean() > 0.5 and len(np.unique(keys[empty])) == 1
    group = zarr.open_group(tmp_path / "s.zarr", mode="w")
    group.create_array("frames", data=frames)
    group.create_array("codes_local", data=keys[None].astype(np.int32))  # a code per content
    noisy = np.where(empty, np.random.default_rng(0).integers(0, 50, keys.shape), keys + 50)
    group.create_array("codes_noisy", data=noisy[None].astype(np.int32))  # empty road gets one of 50 codes
    local, context = (code_statistics(str(tmp_path / "s.zarr"), c, 1) for c in ("codes_local", "codes_noisy"))
    assert local["codes_of_empty_patch"] == 1 and local["codes_per_content"] == 1.0
    assert context["codes_of_empty_patch"] == 50 and context["codes_per_content"] > 1.0
    assert local["distinct_contents"] == len(np.unique(keys)) and local["top4096_content_coverage"] == 1.0
    with pytest.raises(SystemExit):
        main(["--store", str(tmp_path / "s.zarr"), "--codes", "codes_nope"])
    assert "no code array 'codes_nope' (arrays: codes_local, codes_noisy, frames)" in capsys.readouterr().err


def test_distinct_patches_count_every_tile_most_frequent_first(frames):
    from dynplan.data.patches import distinct_patches, tiles

    contents, counts = distinct_patches(frames.numpy(), (4, 4))
    assert counts.sum() == 16 * 12 * 12 and (np.diff(counts) <= 0).all()
    assert contents.shape == (len(counts), 4, 4)
    flat = tiles(frames.numpy(), (4, 4))
    assert (flat[5] == frames[0, :4, 20:24].numpy().ravel()).all()  # tile 5 of frame 0: row 0, column 5
    # the most frequent content really occurs that often, and contents are distinct
    assert (flat == contents[0].ravel()).all(1).sum() == counts[0]
    assert len(np.unique(contents.reshape(len(contents), -1), axis=0)) == len(contents)


def test_content_fitted_codebook_gives_each_frequent_content_a_code_of_its_own(tmp_path, store):
    config = VQVAEConfig(name="tiny-contents", channels=(32, 64), strides=(2, 2), residual_blocks=1, latent_dim=16,
                         codebook_size=64, likelihood="categorical", local=True, codebook_fit="contents",
                         calibrate_decoder=True, batch_size=64, learning_rate=3e-3)  # fmt: skip
    budget = TrainBudget(epochs=3, steps_per_epoch=150, val_frames=100, threads=1)
    path = train_vqvae(store, tmp_path, config, budget)
    history = torch.load(path, weights_only=False)["history"]
    assert history[-1]["reconstruction"] < 0.7 * history[0]["reconstruction"]
    assert history[-1]["contents_exact"] > history[0]["contents_exact"]
    assert 0 < history[-1]["contents_coverage"] <= 1
    assert 0 <= history[-1]["codes_at_lowest_sharpness"] < 1
    model = load_vqvae_checkpoint(path)
    assert (model.code_sharpness != 1).any()  # the calibration travels with the checkpoint
    train = FrameDataset(str(store), "train")
    frames = np.stack([train.array[int(e)] for e in train.episodes])
    contents, _ = content_sample(frames, (4, 4), 64)
    # each of the K most frequent contents is its own code, in frequency order, and decodes as the autoencoder does
    codes = model.encode(torch.from_numpy(contents)).reshape(-1)
    assert (codes == torch.arange(64)).all()
    with torch.no_grad():
        autoencoded = model.pixel.mid(model.autoencode_params(torch.from_numpy(contents)))
    assert (model.decode(codes.view(-1, 1, 1)) == autoencoded).all()


def test_content_fit_needs_a_patch_local_model():
    with pytest.raises(ConfigError, match="codebook_fit='contents' needs local=True"):
        VQVAEConfig(codebook_fit="contents")


def test_decoder_calibration_needs_a_content_fitted_categorical_model():
    with pytest.raises(ConfigError, match="calibrate_decoder needs codebook_fit='contents'"):
        VQVAEConfig(calibrate_decoder=True)
    assert PRESETS["default"].calibrate_decoder


def test_calibrated_codes_sample_as_certainly_as_the_data_and_keep_their_mid_point(frames):
    contents, counts = (torch.from_numpy(a) for a in distinct_patches(frames.numpy(), (2, 2)))
    k = len(contents)  # every content a code of its own: each code's data are certain
    config = VQVAEConfig(channels=(16,), strides=(2,), latent_dim=4, codebook_size=k, likelihood="categorical",
                         local=True, codebook_fit="contents", calibrate_decoder=True)  # fmt: skip
    torch.manual_seed(0)
    model = VQVAE(config)
    optimiser = torch.optim.Adam(model.parameters(), lr=1e-2)
    for _ in range(300):  # autoencode the contents, as the contents fit does
        loss = model.reconstruction_loss(model.autoencode_params(contents), contents)
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    model.eval().fit_codebook(contents)
    codes = model.encode(frames)
    exact = (model.decode(torch.arange(k).view(k, 1, 1)) == contents).flatten(1).all(1)
    assert exact.float().mean() > 0.9
    mid_before, params_before = model.decode(codes), model.decode_params(codes)
    samples_before = model.decode_samples(codes, 10)
    sharpness = model.calibrate(contents, counts)
    assert sharpness.shape == (k,) and (sharpness > 0).all()
    assert (model.decode(codes) == mid_before).all()  # a positive scale keeps every argmax
    nll = lambda params: Categorical().nll(params, frames).sum().item()  # noqa: E731
    assert nll(model.decode_params(codes)) < nll(params_before)
    # codes that decode their content exactly are made as certain as the grid allows, and sample it
    assert (sharpness[exact] == SHARPNESS_GRID.max()).all()
    samples = model.decode_samples(codes, 10)
    certain = exact[codes].repeat_interleave(2, 1).repeat_interleave(2, 2)
    assert (samples[:, certain] == frames[certain]).all()
    assert (samples_before != frames).sum() > (samples != frames).sum()


def test_a_calibrated_tokenizer_can_start_from_an_uncalibrated_ones_weights(tmp_path):
    from dynplan.models import checkpoint
    from dynplan.training.loop import warm_start

    plain = VQVAEConfig(channels=(16,), strides=(2,), latent_dim=4, codebook_size=8, likelihood="categorical",
                        local=True, codebook_fit="contents")  # fmt: skip
    source = VQVAE(plain)
    path = checkpoint.save(tmp_path / "vqvae.pt", {"kind": "vqvae", "config": plain.model_dump(), "epoch": 1,
                                                   "model": source.state_dict()})  # fmt: skip
    calibrated = VQVAE(VQVAEConfig(**{**plain.model_dump(), "calibrate_decoder": True}))
    calibrated.code_sharpness.fill_(7.0)
    warm_start(calibrated, str(path), "vqvae")
    torch.testing.assert_close(calibrated.decoder[-1].weight, source.decoder[-1].weight)
    assert (calibrated.code_sharpness == 1).all()  # an uncalibrated decoder's scale
    back = VQVAE(plain)
    path = checkpoint.save(tmp_path / "calibrated.pt", {"kind": "vqvae", "config": calibrated.config.model_dump(),
                                                        "epoch": 1, "model": calibrated.state_dict()})  # fmt: skip
    warm_start(back, str(path), "vqvae")  # the other way: the scales are dropped
    torch.testing.assert_close(back.decoder[-1].weight, source.decoder[-1].weight)


def test_encode_and_decode_take_numpy_and_return_what_they_are_given():
    from dynplan.models import load_vqvae

    tokenizer = load_vqvae()
    frames = generate_world(RoadConfig(), 1_000_000).frames[:8]  # uint8 numpy, as the env gives them
    codes = tokenizer.encode(frames)
    assert isinstance(codes, np.ndarray) and codes.shape == (8, 12, 12) and codes.dtype == np.int64
    assert torch.equal(torch.from_numpy(codes), tokenizer.encode(torch.from_numpy(frames)))
    decoded = tokenizer.decode(codes.astype(np.uint16))  # the store's code dtype
    assert isinstance(decoded, np.ndarray) and decoded.dtype == np.uint8 and decoded.shape == frames.shape
    assert tokenizer.encode(frames[0]).shape == (12, 12) and tokenizer.decode(codes[0]).shape == (48, 48)
    for call, message in [
        (
            lambda: tokenizer.encode(frames.astype(np.float32)),
            re.escape(
                "VQVAE.encode: frames must be uint8 frames (N, H, W) or one (H, W); got float32 of shape (8, 48, 48)"
            ),
        ),
        (lambda: tokenizer.encode(frames[None]), re.escape("got uint8 of shape (1, 8, 48, 48)")),
        (lambda: tokenizer.decode(codes.astype(np.float64)), "VQVAE.decode: codes must be integer codes"),
        (lambda: tokenizer.decode(codes + 4096), r"codes must lie in \[0, 4096\)"),
    ]:
        with pytest.raises(ValueError, match=message):
            call()
    with pytest.raises(TypeError, match="VQVAE.encode: frames must be a numpy array or a torch tensor"):
        tokenizer.encode(frames.tolist())


def test_fewer_epochs_than_a_run_has_trained_are_refused_naming_the_run(tmp_path, store, capsys):
    """A run keeps only its last epoch's weights: asking `flows.train` for fewer epochs than it has would return
    weights of more epochs than asked, so the command refuses, naming the run and what it holds."""
    import flows.train
    from dynplan.training.runs import vqvae_run_dir

    run_dir = vqvae_run_dir(
        str(store), str(tmp_path), PRESETS["default"].model_dump(), TrainBudget(epochs=2).model_dump()
    )
    run_dir.mkdir(parents=True)
    torch.save({"kind": "vqvae", "epoch": 3}, run_dir / "vqvae.pt")
    with pytest.raises(SystemExit) as caught:
        flows.train.main(["vqvae", "--store", str(store), "--out", str(tmp_path), "--epochs", "2"])
    error = capsys.readouterr().err.strip().splitlines()[-1]
    assert caught.value.code == 2 and f"--epochs 2: the run {run_dir} has trained 3 epochs" in error
    assert "ask --epochs 3 or more, or train a 2-epoch run under another --out" in error
    with pytest.raises(ValueError, match=re.escape(f"epochs 2: the run {run_dir} has trained 3 epochs")):
        train_vqvae(store, run_dir, PRESETS["default"], TrainBudget(epochs=2))  # the library refuses it too
