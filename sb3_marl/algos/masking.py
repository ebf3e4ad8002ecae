"""Where the maskable learners lived until 2026-12 (one module): their names, re-exported, so that
code importing them from here keeps working. The learners are now one per module (``a2c``,
``ppo``, ``acktr``, ``dqn``, ``trpo``), with ``base``, ``buffers``, ``teacher`` and ``rule_prior``."""

from sb3_marl.algos.a2c import MaskableA2C
from sb3_marl.algos.acktr import MaskableACKTR
from sb3_marl.algos.base import (
    ACTOR_CRITIC_POLICIES,
    ActionMaskingMixin,
    MaskingLearner,
    uses_action_masks,
)
from sb3_marl.algos.buffers import MaskedReplayBuffer, PerAgentDictRolloutBuffer, PerAgentRolloutBuffer
from sb3_marl.algos.dqn import MaskableDQN
from sb3_marl.algos.ppo import MaskableActorCritic, MaskedPPO
from sb3_marl.algos.rule_prior import RulePriorLearner
from sb3_marl.algos.teacher import SupervisorTeacher, check_safety_loss_coef, executed_labels
from sb3_marl.algos.trpo import SafeTRPO

__all__ = [
    "ACTOR_CRITIC_POLICIES",
    "ActionMaskingMixin",
    "MaskableA2C",
    "MaskableACKTR",
    "MaskableActorCritic",
    "MaskableDQN",
    "MaskedPPO",
    "MaskedReplayBuffer",
    "MaskingLearner",
    "PerAgentDictRolloutBuffer",
    "PerAgentRolloutBuffer",
    "RulePriorLearner",
    "SafeTRPO",
    "SupervisorTeacher",
    "check_safety_loss_coef",
    "executed_labels",
    "uses_action_masks",
]
