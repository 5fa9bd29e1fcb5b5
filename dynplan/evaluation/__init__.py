"""Evaluation over recorded episodes (the paper's Table 1 protocol, docs/protocol.md §4): the techniques, the
cases, the results store with its provenance, Table 1 and replays."""

from dynplan.lazy import lazy_names

#: Each public name by its module, imported when first used (`dynplan.lazy`).
_PUBLIC = {
    "AgentInputs": "dynplan.evaluation.techniques",
    "AgentSpec": "dynplan.evaluation.agent",
    "Case": "dynplan.evaluation.cases",
    "Run": "dynplan.evaluation.store",
    "StoreError": "dynplan.evaluation.store",
    "TECHNIQUES": "dynplan.evaluation.techniques",
    "Technique": "dynplan.evaluation.techniques",
    "aggregate": "dynplan.evaluation.table",
    "cases": "dynplan.evaluation.cases",
    "evaluation_rows": "dynplan.evaluation.store",
    "pending": "dynplan.evaluation.protocol",
    "plan_episode": "dynplan.evaluation.protocol",
    "register_technique": "dynplan.evaluation.techniques",
    "render_markdown": "dynplan.evaluation.table",
    "run_case": "dynplan.evaluation.protocol",
}
__getattr__, __dir__ = lazy_names(__name__, _PUBLIC)
__all__ = sorted(_PUBLIC)
