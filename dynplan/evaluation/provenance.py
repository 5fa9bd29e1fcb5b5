"""What a result depends on besides its case — playouts, the recorded log's bytes, the world model's weights and
caution — for each row (`provenance`) and for a run's manifest (`world_model_entry`, `begin_run`)."""

from __future__ import annotations

import os
from pathlib import Path

from dynplan.data.collect import log_path
from dynplan.evaluation.agent import AgentSpec
from dynplan.evaluation.cases import Case
from dynplan.evaluation.store import Run
from dynplan.files import sha256_file
from dynplan.models.registry import caution_for
from dynplan.models.weights import weights_sha256, world_model_paths

#: The checkout: paths inside it are recorded relative to it, so a manifest reads the same on every machine.
_ROOT = Path(__file__).resolve().parents[2]


def _shown(path: Path) -> str:
    resolved = Path(path).resolve()
    return str(resolved.relative_to(_ROOT)) if _ROOT in resolved.parents else str(path)


def _world_model_identity(model: str, model_dir: str | None) -> str:
    """SHA-256 of the checkpoints a learned technique of configuration `model` plays with."""
    return "+".join(weights_sha256(p) if p.exists() else "missing" for p in world_model_paths(model, model_dir))


def provenance(case: Case, log_dir: str | os.PathLike, spec: AgentSpec | None = None) -> dict:
    """What a result depends on besides the case: the playouts, the log's bytes, and the world model's weights and
    caution (the configuration's own where `spec` does not override it; only the settings that are on are
    recorded, so that results from before a setting existed stay valid)."""
    spec = spec or AgentSpec()
    source = log_path(log_dir, case.seed)
    provenance = {"playouts": spec.playouts, "log_sha256": sha256_file(source) if source.exists() else None}
    if case.model is not None:
        provenance["world_model_sha256"] = _world_model_identity(case.model, spec.model_dir)
        provenance.update(caution_for(case.model, spec.caution).recorded())
    return provenance


def world_model_entry(model: str, spec: AgentSpec | None = None) -> dict:
    """What a run's manifest records of world-model configuration `model`: its weights and their SHA-256, and the
    caution it plays with (only the settings that are on)."""
    spec = spec or AgentSpec()
    return {
        "weights_sha256": _world_model_identity(model, spec.model_dir),
        "weights": [_shown(p) for p in world_model_paths(model, spec.model_dir)],
        "caution": caution_for(model, spec.caution).recorded(),
    }


def begin_run(
    run: Run, role: str, all_cases: list[Case], log_dir: str | os.PathLike, command: str, spec: AgentSpec | None = None
) -> dict:
    """Write (or extend) `run`'s manifest with what these cases play with: seeds, logs, weights, caution."""
    spec = spec or AgentSpec()
    seeds = sorted({c.seed for c in all_cases})
    logs = {s: sha256_file(p) if (p := log_path(log_dir, s)).exists() else None for s in seeds}
    models = sorted({c.model for c in all_cases if c.model is not None})
    return run.begin(role, spec.playouts, seeds, logs, {m: world_model_entry(m, spec) for m in models}, command)
