"""Training precision: bfloat16 autocast only on a device that has it, in a run folder of its own, recorded in the
run's checkpoints; a small real bfloat16 training (emulated where the CPU lacks the instructions) learns as float32
does."""

import pytest
import torch

from dynplan.config import ConfigError
from dynplan.training import precision as precision_module
from dynplan.training.budget import TrainBudget


def test_bfloat16_on_a_cpu_without_it_is_one_line_naming_what_is_valid(monkeypatch):
    monkeypatch.setattr(precision_module, "_cpu_flags", lambda: {"avx2", "fma"})
    with pytest.raises(
        ConfigError, match=r"precision='bfloat16': this CPU has no bfloat16 instructions .*valid here: float32"
    ):
        TrainBudget(precision="bfloat16")
    monkeypatch.setattr(precision_module, "_cpu_flags", lambda: {"avx2", "avx512f", "avx512_bf16"})
    assert TrainBudget(precision="bfloat16").precision == "bfloat16"
    with pytest.raises(ConfigError, match="precision"):
        TrainBudget(precision="float16")


def test_float32_is_neutral_and_bfloat16_names_a_run_folder_of_its_own(monkeypatch):
    from dynplan.training.runs import _run_dir

    monkeypatch.setattr(precision_module, "_cpu_flags", lambda: {"avx512_bf16"})
    assert "precision" not in TrainBudget().model_dump()  # earlier runs keep their folders
    folders = {_run_dir("pixelcnn", "out", {"name": "x"}, TrainBudget(precision=p).model_dump(), [], "v") for p in
               ("float32", "bfloat16")}  # fmt: skip
    assert len(folders) == 2


def test_a_small_bfloat16_training_learns_and_records_its_precision(tmp_path, recorded_logs, monkeypatch):
    from dynplan.data.build import build_frame_store_from_logs
    from dynplan.data.store import list_logs
    from dynplan.models.configs import PixelCNNConfig, VQVAEConfig
    from dynplan.training.codes import build_codes
    from dynplan.training.pixelcnn import train_pixelcnn
    from dynplan.training.vqvae import train_vqvae

    monkeypatch.setattr(precision_module, "_cpu_flags", lambda: {"avx512_bf16"})  # emulated where the CPU lacks it
    store = tmp_path / "frames.zarr"
    build_frame_store_from_logs(store, list_logs(recorded_logs))
    tokenizer = VQVAEConfig(name="tiny", channels=(8, 8, 8), strides=(2, 2, 2), latent_dim=4, codebook_size=16,
                            likelihood="categorical", local=True, codebook_fit="contents", batch_size=8)  # fmt: skip
    vq = train_vqvae(store, tmp_path / "vq", tokenizer, TrainBudget(epochs=1, steps_per_epoch=20, val_frames=50,
                                                                    threads=1, precision="bfloat16"))  # fmt: skip
    assert torch.load(vq, weights_only=False)["precision"] == "bfloat16"
    build_codes(store, vq, "tiny")
    config = PixelCNNConfig(codebook_size=16, channels=8, layers=4, embed_dim=4, condition_channels=8, batch_size=16,
                            learning_rate=3e-3)  # fmt: skip
    histories = {}
    for precision in ("float32", "bfloat16"):
        budget = TrainBudget(epochs=3, steps_per_epoch=25, val_frames=32, threads=1, precision=precision)
        path = train_pixelcnn(store, "codes_tiny", tmp_path / precision, config, budget)
        state = torch.load(path, weights_only=False)
        assert state["precision"] == precision
        assert torch.load(tmp_path / precision / "checkpoint.pt", weights_only=False)["precision"] == precision
        assert all(p.dtype == torch.float32 for p in state["model"].values() if p.is_floating_point())
        histories[precision] = state["history"]
    bf16, f32 = histories["bfloat16"], histories["float32"]
    assert bf16[-1]["loss"] < 0.8 * bf16[0]["loss"]
    assert bf16[-1]["val_loss"] == pytest.approx(f32[-1]["val_loss"], rel=0.05)  # validation is scored in float32


def test_bench_precision_times_both_precisions_and_says_whether_the_cpu_has_bfloat16():
    from dynplan.bench.precision import bench_precision

    case = bench_precision(steps=1, repeats=1, threads=1, presets=("paper",), batch=2)["prior paper"]
    assert case["float32_windows_per_s"] > 0 and case["bfloat16_windows_per_s"] > 0
    assert case["bfloat16_speedup"] == pytest.approx(case["bfloat16_windows_per_s"] / case["float32_windows_per_s"],
                                                     abs=0.01)  # fmt: skip
    native = precision_module.bfloat16_missing(torch.device("cpu")) is None
    assert case["bfloat16_native"] == "yes" if native else case["bfloat16_native"].startswith("no: this CPU")
