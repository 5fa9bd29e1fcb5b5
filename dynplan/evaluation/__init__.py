"""Evaluation over recorded episodes (the paper's Table 1 protocol, docs/protocol.md §4): the techniques, the
cases, the results store with its provenance, Table 1 and replays."""

from dynplan.evaluation.agent import AgentSpec
from dynplan.evaluation.cases import Case, cases
from dynplan.evaluation.protocol import pending, plan_episode, run_case
from dynplan.evaluation.store import Run, StoreError, evaluation_rows
from dynplan.evaluation.table import aggregate, render_markdown
from dynplan.evaluation.techniques import TECHNIQUES, AgentInputs, Technique, register_technique

__all__ = [
    "TECHNIQUES",
    "AgentInputs",
    "AgentSpec",
    "Case",
    "Run",
    "StoreError",
    "Technique",
    "aggregate",
    "cases",
    "evaluation_rows",
    "pending",
    "plan_episode",
    "register_technique",
    "render_markdown",
    "run_case",
]
