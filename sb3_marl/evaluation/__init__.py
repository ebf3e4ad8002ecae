"""Evaluation of driving policies on the scenarios, knowing nothing of learners: the one episode
runner and both supervisor protocols (:mod:`~sb3_marl.evaluation.episodes`), the paper's metrics
and tables (:mod:`~sb3_marl.evaluation.metrics`), the hand-written reference policies
(:mod:`~sb3_marl.evaluation.baselines`), videos, learning-curve plots and the policy
interpretation of experiment 6. A policy is a callable ``policy(env, obs) -> actions``;
:func:`sb3_marl.algos.common.policies.model_policy` makes one of a trained model."""

from sb3_marl.evaluation.episodes import (
    PROTOCOLS,
    SUPERVISOR_PROTOCOLS,
    Policy,
    StepHook,
    evaluate_on_density,
    evaluate_protocols,
    evaluation_records,
    protocol_label,
    protocol_records,
    protocol_result,
    protocol_rows,
    run_episodes,
    with_supervisor,
)
from sb3_marl.evaluation.metrics import (
    MERGE_COLUMNS,
    TABLE_COLUMNS,
    CooperativeLaneChange,
    EpisodeRecord,
    EpisodeTrace,
    markdown_table,
    summarize,
)

__all__ = [
    "MERGE_COLUMNS",
    "PROTOCOLS",
    "SUPERVISOR_PROTOCOLS",
    "TABLE_COLUMNS",
    "CooperativeLaneChange",
    "EpisodeRecord",
    "EpisodeTrace",
    "Policy",
    "StepHook",
    "evaluate_on_density",
    "evaluate_protocols",
    "evaluation_records",
    "markdown_table",
    "protocol_label",
    "protocol_records",
    "protocol_result",
    "protocol_rows",
    "run_episodes",
    "summarize",
    "with_supervisor",
]
