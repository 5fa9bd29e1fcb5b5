"""The road's part of `collect-train-eval` (`dynplan.world_parts.PipelineStages`): a preset's Table 1 cases over
the recorded evaluation episodes (shared by presets, in `eval_logs` beside the presets' folders), and the report's
results section — Table 1 and the learned model's pictures."""

from __future__ import annotations

from pathlib import Path

from dynplan.evaluation.agent import AgentSpec
from dynplan.evaluation.cases import EVAL_SEED_START, CasePlan
from dynplan.evaluation.table import aggregate, load_results
from dynplan.pipeline.presets import PipelinePreset
from dynplan.pipeline.report import draw_figures, figures_section, table_section
from dynplan.worlds.road.evaluate import RoadEvaluation


def eval_logs(work: Path) -> Path:
    """The road's recorded evaluation episodes, shared by the presets whose folders sit beside it."""
    return Path(work).parent / "eval_logs"


class Stages:
    """The road's evaluation and report in `collect-train-eval`."""

    def evaluations(self, preset: PipelinePreset, work: Path) -> list[RoadEvaluation]:
        e = preset.evaluation
        cases = CasePlan(
            techniques=e.techniques,
            models=preset.models,
            agent_speeds=e.agent_speeds,
            rollout_steps=e.rollout_steps,
            episodes=e.episodes,
        )
        agent = AgentSpec(playouts=e.playouts, model_dir=str(work / "models"))
        return [
            RoadEvaluation(plan=cases, agent=agent, log_dir=str(eval_logs(work)), results_dir=str(work / "results"))
        ]

    def report(self, preset: PipelinePreset, work: Path, out: Path, command: str) -> list[str]:
        figures = None
        if preset.learned_techniques:
            figures = draw_figures(
                out,
                {m: work / "models" / m for m in preset.models},
                eval_logs(work),
                EVAL_SEED_START,
                preset.evaluation.rollout_steps[0],
                preset.report_episodes,
                preset.learned_techniques[0],
            )
        rows = aggregate(load_results(work / "results")) if (work / "results").exists() else []
        return table_section(rows) + figures_section(figures)
