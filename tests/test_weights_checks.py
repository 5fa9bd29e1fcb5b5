"""Weights are checked up front, in one place (`dynplan.models.checkpoint.verify`), by every loader and command:
their tensors against the configuration they record, their values, their model card and, where a configuration is
asked for, that they are its weights. Each case damages a real copy of the committed weights."""

import json
import shutil
from pathlib import Path

import pytest
import torch

import flows.evaluate
import flows.replay
import flows.train
from dynplan.data.build import build_frame_store
from dynplan.data.collect import record_episode
from dynplan.data.store import inspect_for_store
from dynplan.evaluation.agent import AgentSpec
from dynplan.models import checkpoint
from dynplan.models.checkpoint import (
    CheckpointError,
    UnreadableCheckpoint,
    load_pixelcnn_checkpoint,
    load_vqvae_checkpoint,
)
from dynplan.models.weights import pretrained_path, weights_sha256
from dynplan.models.world_model import load_world_model

#: Imported with the test module: Prefect binds its log handlers to the streams of the moment.
TRAIN, EVALUATE, REPLAY = flows.train.main, flows.evaluate.main, flows.replay.main


def _folder(root: Path, vqvae: str = "default", pixelcnn: str = "default") -> Path:
    """A model folder `root/default/{vqvae,pixelcnn}.pt` holding copies of the committed weights of the named
    configurations."""
    (root / "default").mkdir(parents=True)
    shutil.copyfile(pretrained_path("vqvae", vqvae), root / "default" / "vqvae.pt")
    shutil.copyfile(pretrained_path("pixelcnn", pixelcnn), root / "default" / "pixelcnn.pt")
    return root


def _edit(source: Path, target: Path, name: str, change) -> Path:
    """`source`'s checkpoint with tensor `name` replaced by `change(tensor)`, saved by torch at `target`."""
    state = torch.load(source, map_location="cpu", weights_only=False)
    state["model"][name] = change(state["model"][name].clone())
    torch.save(state, target)
    return target


def _nan(tensor: torch.Tensor) -> torch.Tensor:
    tensor.view(-1)[7] = float("nan")
    return tensor


def _refused(root: Path) -> str:
    with pytest.raises(CheckpointError) as error:
        AgentSpec(technique="samples5", model_dir=str(root)).check_weights()
    assert "\n" not in str(error.value)
    return str(error.value)


def test_the_committed_weights_pass_and_are_what_their_cards_describe():
    for stage in ("vqvae", "pixelcnn"):
        for model in ("default", "paper"):
            path = pretrained_path(stage, model)
            state = checkpoint.verify(path, stage, configuration=model)
            card = json.loads(path.with_suffix(".json").read_text())
            assert card["sha256"] == weights_sha256(path) and card["config"]["name"] == model
            assert state["config"]["name"] == model


def test_a_model_folder_of_good_copies_loads_the_committed_weights(tmp_path):
    root = _folder(tmp_path)
    AgentSpec(technique="samples5", model_dir=str(root)).check_weights()
    prior = load_pixelcnn_checkpoint(root / "default" / "pixelcnn.pt", configuration="default")
    committed = torch.load(pretrained_path("pixelcnn", "default"), weights_only=False)["model"]
    assert all(torch.equal(value, committed[name]) for name, value in prior.state_dict().items())


def test_the_papers_weights_copied_over_the_defaults_are_named_as_such(tmp_path):
    root = _folder(tmp_path, "paper", "paper")
    assert _refused(root) == (f"{root}/default/vqvae.pt: its configuration is 'paper''s, not 'default''s (it does not "
                              "match the model card vqvae-default.json; it is a copy of vqvae-paper.pt)")  # fmt: skip
    shutil.copyfile(pretrained_path("vqvae", "default"), root / "default" / "vqvae.pt")
    assert _refused(root).startswith(f"{root}/default/pixelcnn.pt: its configuration is 'paper''s, not 'default''s")
    with pytest.raises(CheckpointError, match=r"pixelcnn.pt: its configuration is 'paper''s, not 'default''s"):
        load_world_model(root / "default", model="default")


def test_a_tensor_of_another_shape_is_named_with_the_shape_its_configuration_needs(tmp_path):
    root = _folder(tmp_path)
    prior = root / "default" / "pixelcnn.pt"
    _edit(prior, prior, "head.3.weight", lambda t: t[:100])
    assert _refused(root) == (f"{prior}: tensor 'head.3.weight' has shape (100, 32, 1, 1) but configuration "
                              "'default' needs (4096, 32, 1, 1)")  # fmt: skip
    tokenizer = root / "default" / "vqvae.pt"
    _edit(pretrained_path("vqvae", "default"), tokenizer, "encoder.0.weight", lambda t: t[:16])
    with pytest.raises(CheckpointError, match=r"vqvae.pt: tensor 'encoder.0.weight' has shape \(16, 1, 2, 2\) but "
                       r"configuration 'default' needs \(32, 1, 2, 2\)$"):  # fmt: skip
        load_vqvae_checkpoint(tokenizer)


def test_a_missing_or_foreign_tensor_is_named(tmp_path):
    source = pretrained_path("pixelcnn", "paper")
    state = torch.load(source, weights_only=False)
    del state["model"]["head.3.bias"]
    torch.save(state, tmp_path / "lacking.pt")
    with pytest.raises(CheckpointError, match=r"lacking.pt: lacks tensor 'head.3.bias' of shape \(512\), which "
                       r"configuration 'paper' needs$"):  # fmt: skip
        load_pixelcnn_checkpoint(tmp_path / "lacking.pt")
    state["model"]["head.3.bias"], state["model"]["extra.weight"] = torch.zeros(512), torch.zeros(3)
    torch.save(state, tmp_path / "extra.pt")
    with pytest.raises(CheckpointError, match="extra.pt: holds tensor 'extra.weight', which configuration 'paper' "
                       "does not have$"):  # fmt: skip
        load_pixelcnn_checkpoint(tmp_path / "extra.pt")
    state["config"] = {**state["config"], "channels": 2}
    torch.save(state, tmp_path / "invalid.pt")
    with pytest.raises(CheckpointError, match=r"invalid.pt: its recorded configuration is invalid: .*channels=2"):
        load_pixelcnn_checkpoint(tmp_path / "invalid.pt")


def test_nan_or_inf_values_are_named_by_their_tensor(tmp_path):
    root = _folder(tmp_path)
    prior = root / "default" / "pixelcnn.pt"
    _edit(pretrained_path("pixelcnn", "default"), prior, "embed.weight", _nan)
    assert _refused(root) == f"{prior}: tensor 'embed.weight' holds NaN/inf values"
    tokenizer = _edit(pretrained_path("vqvae", "default"), tmp_path / "inf.pt", "decoder.6.bias",
                      lambda t: t.fill_(float("inf")))  # fmt: skip
    with pytest.raises(CheckpointError, match="inf.pt: tensor 'decoder.6.bias' holds NaN/inf values$"):
        load_vqvae_checkpoint(tokenizer)


def test_a_truncated_checkpoint_is_named(tmp_path):
    root = _folder(tmp_path)
    prior = root / "default" / "pixelcnn.pt"
    prior.write_bytes(pretrained_path("pixelcnn", "default").read_bytes()[:100_000])
    with pytest.raises(UnreadableCheckpoint, match=f"{prior}: not a readable checkpoint"):
        AgentSpec(model_dir=str(root)).check_weights()


def test_weights_unlike_their_model_card_are_refused(tmp_path):
    """A card beside the weights (`<name>.json`, as the committed ones have) is compared with the file."""
    path, card = tmp_path / "vqvae-default.pt", tmp_path / "vqvae-default.json"
    shutil.copyfile(pretrained_path("vqvae", "default"), path)
    shutil.copyfile(pretrained_path("vqvae", "default").with_suffix(".json"), card)
    assert load_vqvae_checkpoint(path).config.name == "default"
    _edit(pretrained_path("vqvae", "default"), path, "decoder.6.bias", lambda t: t + 0.5)  # same shapes, finite
    with pytest.raises(CheckpointError, match=f"{path}: its SHA-256 is not the one its model card {card} records"):
        load_vqvae_checkpoint(path)
    shutil.copyfile(pretrained_path("vqvae", "paper"), path)
    with pytest.raises(CheckpointError, match=f"{path}: its configuration is 'paper''s, not 'default''s \\(it does "
                       f"not match the model card {card}\\)"):  # fmt: skip
        load_vqvae_checkpoint(path)
    shutil.copyfile(pretrained_path("vqvae", "default"), path)
    described = json.loads(card.read_text())
    card.write_text(json.dumps({**described, "config": {**described["config"], "latent_dim": 16}}))
    with pytest.raises(CheckpointError, match=f"{path}: its configuration differs from its model card {card} in "
                       "latent_dim$"):  # fmt: skip
        load_vqvae_checkpoint(path)
    card.write_text(json.dumps({**described, "stage": "pixelcnn"}))
    with pytest.raises(CheckpointError, match="a 'vqvae' checkpoint, but its model card .* describes a 'pixelcnn'"):
        load_vqvae_checkpoint(path)
    card.write_text(json.dumps(described)[:200])
    with pytest.raises(CheckpointError, match=f"{card}: the model card of vqvae-default.pt is not readable JSON"):
        load_vqvae_checkpoint(path)


def _exit_2(main, argv: list[str], capsys) -> str:
    with pytest.raises(SystemExit) as stop:
        main(argv)
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert "Traceback" not in "\n".join(err)
    return err[-1]


def test_train_checks_init_from_before_the_flow_starts(tmp_path, capsys):
    """Shapes, values and fit to the run are checked before the store's contents are: a good warm start gets as far
    as the store's missing code array."""
    record_episode(tmp_path / "logs", 3)
    store = str(tmp_path / "store.zarr")
    build_frame_store(store, [inspect_for_store(p) for p in (tmp_path / "logs").glob("*.mcap")])
    nan = _edit(pretrained_path("pixelcnn", "default"), tmp_path / "nan.pt", "embed.weight", _nan)
    line = _exit_2(TRAIN, ["pixelcnn", "--store", store, "--init-from", str(nan)], capsys)
    assert line.endswith(f"--init-from {nan}: tensor 'embed.weight' holds NaN/inf values")
    cut = _edit(pretrained_path("pixelcnn", "default"), tmp_path / "cut.pt", "conditioner.0.weight", lambda t: t[:8])
    line = _exit_2(TRAIN, ["pixelcnn", "--store", store, "--init-from", str(cut)], capsys)
    assert line.endswith(f"--init-from {cut}: tensor 'conditioner.0.weight' has shape (8, 128, 3, 3) but "
                         "configuration 'default' needs (64, 128, 3, 3)")  # fmt: skip
    paper = str(pretrained_path("pixelcnn", "paper"))
    line = _exit_2(TRAIN, ["pixelcnn", "--store", store, "--init-from", paper], capsys)
    assert line.endswith(f"--init-from {paper}: cannot start this run from it: the architecture differs "
                         "(embed.weight: (512, 64) vs (4096, 32))")  # fmt: skip
    good = str(pretrained_path("pixelcnn", "default"))  # the committed weights start a run of their configuration
    line = _exit_2(TRAIN, ["pixelcnn", "--store", store, "--init-from", good], capsys)
    assert line.endswith(f"{store}: no codes_default; train the VQ-VAE first (python -m flows.train vqvae --model "
                         "default)")  # fmt: skip


def test_evaluate_and_replay_name_the_copied_weights_before_playing(tmp_path, capsys):
    root = _folder(tmp_path / "models", "paper", "paper")
    line = _exit_2(EVALUATE, ["--techniques", "samples5", "--model-dir", str(root), "--episodes", "1"], capsys)
    assert line.endswith(f"--model-dir {root}: {root}/default/vqvae.pt: its configuration is 'paper''s, not "
                         "'default''s (it does not match the model card vqvae-default.json; it is a copy of "
                         "vqvae-paper.pt)")  # fmt: skip
    log = record_episode(tmp_path / "logs", 3).path
    shutil.copyfile(pretrained_path("vqvae", "default"), root / "default" / "vqvae.pt")
    _edit(pretrained_path("pixelcnn", "default"), root / "default" / "pixelcnn.pt", "embed.weight", _nan)
    line = _exit_2(REPLAY, [str(log), "--planner", "model", "--model-dir", str(root), "--out",
                            str(tmp_path / "r.mcap")], capsys)  # fmt: skip
    assert line.endswith(f"{root}/default/pixelcnn.pt: tensor 'embed.weight' holds NaN/inf values")
    assert not (tmp_path / "r.mcap").exists()


def test_a_tokenizer_that_cannot_take_the_configurations_caution_is_named(tmp_path):
    """A variant of 'default' (its name, another architecture: a pipeline's overrides) without patch-local codes
    cannot take the default's occupancy: the tokenizer's file is named before anything plays."""
    root = tmp_path / "models"
    (root / "default").mkdir(parents=True)
    for stage in ("vqvae", "pixelcnn"):
        state = torch.load(pretrained_path(stage, "paper"), weights_only=False)
        state["config"] = {**state["config"], "name": "default"}
        torch.save(state, root / "default" / f"{stage}.pt")
    assert _refused(root) == (f"{root}/default/vqvae.pt: occupancy=0.1 needs a tokenizer with patch-local codes "
                              "(local=True); 'default' has none (use occupancy=0)")  # fmt: skip
    AgentSpec(technique="samples5", model_dir=str(root), caution={"occupancy": 0.0}).check_weights()
