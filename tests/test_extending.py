"""Extending dynplan without touching it: a world-model configuration and a technique registered at run time play
through flows.evaluate, Table 1 and flows.replay; docs/extending.md's examples run as written."""

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from dynplan.data.collect import log_path, record_episode
from dynplan.evaluation.agent import AgentSpec
from dynplan.evaluation.cases import EVAL_SEED_START
from dynplan.evaluation.replay import replay
from dynplan.evaluation.table import render_markdown
from dynplan.evaluation.techniques import TECHNIQUES, Technique, register_technique
from dynplan.models import checkpoint
from dynplan.models.configs import PixelCNNConfig, VQVAEConfig
from dynplan.models.pixelcnn import ConditionalPixelCNN
from dynplan.models.registry import WORLD_MODELS, WorldModelSpec, register_world_model
from dynplan.models.vqvae import VQVAE
from dynplan.planning.forward import ForwardModel, Prediction

ROOT = Path(__file__).resolve().parents[1]
PAGE = (ROOT / "docs" / "extending.md").read_text()


class Persistence(ForwardModel):
    name = "persistence"

    def predict(self, observed: np.ndarray, k: int) -> Prediction:
        return Prediction.from_frames(np.repeat(observed[-1:], k, axis=0))


@pytest.fixture
def extensions(tmp_path):
    """A tiny world-model configuration (untrained weights in a folder) and a persistence technique, registered
    for the test only."""
    spec = register_world_model(WorldModelSpec(
        "tiny", VQVAEConfig(name="tiny", channels=(8, 8), strides=(2, 2), latent_dim=4, codebook_size=16,
                            likelihood="categorical", local=True),
        PixelCNNConfig(name="tiny", codebook_size=16, channels=8, layers=2, condition_channels=8),
    ))  # fmt: skip
    register_technique(Technique("persistence", "the last observed frame, k times", lambda inputs: Persistence()))
    torch.manual_seed(0)
    for stage, model in (("vqvae", VQVAE(spec.tokenizer)), ("pixelcnn", ConditionalPixelCNN(spec.prior))):
        checkpoint.save(tmp_path / "models" / "tiny" / f"{stage}.pt",
                        {"kind": stage, "config": model.config.model_dump(), "model": model.state_dict()})  # fmt: skip
    record_episode(tmp_path / "logs", EVAL_SEED_START)
    try:
        yield tmp_path
    finally:
        WORLD_MODELS.pop("tiny")
        TECHNIQUES.pop("persistence")


def test_registered_world_model_and_technique_run_through_evaluate_table_and_replay(extensions, prefect_api):
    from flows.evaluate import main

    out = extensions
    rows = main(["--techniques", "persistence", "mid", "--models", "tiny", "--model-dir", str(out / "models"),
                 "--agent-speeds", "1.0", "--rollout-steps", "1", "--episodes", "1", "--playouts", "10",
                 "--log-dir", str(out / "logs"), "--results-dir", str(out / "results")])  # fmt: skip
    assert {(r["technique"], r["model"]) for r in rows} == {("persistence", None), ("mid", "tiny")}
    table = render_markdown(rows)
    assert "| 2× persistence (ours) |" in table and "| 2× mid [tiny] (ours) |" in table
    assert table.index("mid [tiny]") < table.index("persistence")  # a registered technique comes after the rest
    log = log_path(out / "logs", EVAL_SEED_START)
    assert replay(log, AgentSpec(technique="persistence", rollout_steps=1, playouts=10), out=out / "p.mcap").steps > 0
    tiny = AgentSpec(technique="mid", model="tiny", model_dir=str(out / "models"), rollout_steps=1, playouts=10)
    learned = replay(log, tiny, out=out / "m.mcap")
    assert learned.outcome in {"goal", "timeout", "death"}


@pytest.mark.slow
@pytest.mark.parametrize("index", range(len(re.findall(r"```python\n", PAGE))))
def test_extending_page_examples_run(index, tmp_path):
    block = re.findall(r"```python\n(.*?)```", PAGE, flags=re.S)[index]
    proc = subprocess.run([sys.executable, "-c", block], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stdout.strip()
