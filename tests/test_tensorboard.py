"""TensorBoard output of training: small real trainings whose event files are read back — every epoch's figures,
the stages' images, a resumed run's whole curve — and the option's one line when the extra is missing."""

import builtins

import pytest
import torch

from dynplan.data.build import build_frame_store_from_logs
from dynplan.data.store import list_logs
from dynplan.models.configs import PixelCNNConfig, VQVAEConfig
from dynplan.training.budget import TrainBudget
from dynplan.training.codes import build_codes
from dynplan.training.pixelcnn import train_pixelcnn
from dynplan.training.tensorboard import read_images, read_scalars
from dynplan.training.vqvae import train_vqvae

TINY = VQVAEConfig(name="tiny", channels=(8, 8, 8), strides=(2, 2, 2), latent_dim=4, codebook_size=16,
                   likelihood="categorical", batch_size=8)  # fmt: skip
BUDGET = TrainBudget(epochs=2, steps_per_epoch=3, val_frames=16, threads=1)


@pytest.fixture(scope="module")
def store(tmp_path_factory, recorded_logs):
    path = tmp_path_factory.mktemp("tb") / "frames.zarr"
    build_frame_store_from_logs(path, list_logs(recorded_logs))
    return path


def test_training_writes_every_epochs_figures_and_images(tmp_path, store):
    board = tmp_path / "board"
    train_vqvae(store, tmp_path / "vq", TINY, BUDGET, tensorboard=board)
    scalars = read_scalars(board)
    assert [step for step, _ in scalars["train/reconstruction"]] == [1, 2]
    for tag in ("val/fn_rate", "val/fp_rate", "val/goal_exact", "val/codes_used", "val/perplexity"):
        assert len(scalars[tag]) == 2, tag
    history = torch.load(tmp_path / "vq" / "vqvae.pt", weights_only=False)["history"]
    assert [v for _, v in scalars["val/fn_rate"]] == pytest.approx([row["val_fn_rate"] for row in history])
    images = read_images(board)
    assert [step for step, _ in images["reconstructions"]] == [1, 2]
    assert images["reconstructions"][0][1] == (6 * 49 - 1, 3 * 48 + 2)  # six columns: true, decoded, error


def test_a_resumed_run_writes_the_epochs_its_folder_lacks_once(tmp_path, store):
    board = tmp_path / "board"
    train_vqvae(store, tmp_path / "vq", TINY, BUDGET.model_copy(update={"epochs": 1}))  # no TensorBoard yet
    train_vqvae(store, tmp_path / "vq", TINY, BUDGET, tensorboard=board)  # epoch 1 from history, then epoch 2
    train_vqvae(store, tmp_path / "vq", TINY, BUDGET.model_copy(update={"epochs": 3}), tensorboard=board)
    scalars = read_scalars(board)
    assert [step for step, _ in scalars["train/loss"]] == [1, 2, 3]  # each epoch once, across three event files
    assert [step for step, _ in read_images(board)["reconstructions"]] == [2, 3]  # pictures of epochs it trained


def test_the_prior_writes_its_predicted_next_frames(tmp_path, store):
    vq = train_vqvae(store, tmp_path / "vq", TINY, BUDGET)
    build_codes(store, vq, "tiny_tb")
    prior = PixelCNNConfig(codebook_size=16, channels=8, layers=2, condition_channels=8, batch_size=8)
    board = tmp_path / "board"
    train_pixelcnn(store, "codes_tiny_tb", tmp_path / "prior", prior, BUDGET, tensorboard=board)
    scalars = read_scalars(board)
    tags = {"train/loss", "train/accuracy", "val/accuracy", "val/next_fn_rate", "val/greedy_grid_exact"}
    assert tags <= set(scalars)
    assert [step for step, _ in read_images(board)["next_frame"]] == [1, 2]


def test_the_option_says_how_to_install_the_extra(store, monkeypatch, capsys):
    from flows.train import main

    real_import = builtins.__import__

    def without_tensorboard(name, *args, **kwargs):
        if name.startswith(("torch.utils.tensorboard", "tensorboard")):
            raise ImportError(f"No module named {name!r}")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", without_tensorboard)
    with pytest.raises(SystemExit):
        main(["vqvae", "--store", str(store), "--tensorboard", "runs"])
    message = "TensorBoard output needs the tensorboard package: pip install -e '.[tensorboard]'"
    assert message in capsys.readouterr().err
