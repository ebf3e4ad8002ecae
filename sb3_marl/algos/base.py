"""What the learners that never sample an unavailable meta-action, as the authors' MA2C (masked logits).

The scenario env says which meta-actions each AV may take (``action_masks()``: FASTER only below
the top target speed, a lane change only towards a reachable lane, ...); the
parameter-sharing VecEnv passes those masks per AV slot. sb3-contrib's maskable policy,
distribution and rollout buffer do the rest:

- :class:`MaskableA2C` (``ma2c``) is A2C's update on sb3-contrib's ``MaskablePPO`` machinery: one
  epoch over the whole rollout in one batch, no clipping and no advantage normalisation make the
  PPO loss's gradient exactly A2C's (the probability ratio is 1 at the single gradient step, and
  the gradient of ``ratio * advantage`` is then ``advantage * ∇ log π``); RMSprop as SB3's A2C.
- :class:`MaskedPPO` (``mappo``) is ``MaskablePPO`` itself.
- :class:`MaskableACKTR` (``maacktr``) is our ACKTR on the same maskable machinery.
- :class:`MaskableDQN` (``madqn``): sb3-contrib has no maskable DQN; SB3's DQN with masked greedy
  actions, exploration and bootstrap targets (masks of next states kept in the replay buffer).

This module holds what they share (the learners are in ``a2c``, ``ppo``, ``acktr``, ``dqn``,
``trpo``; their buffers in ``buffers``, the supervisor teacher in ``teacher``, the rule prior in
``rule_prior``). All take ``action_masking`` (default True): False trains and acts without masks (the unmasked
learner of the ablation) with the same network. The setting is saved with the model, and
``predict(obs, action_masks=...)`` takes masks exactly as sb3-contrib's maskable algorithms do.
"""

from __future__ import annotations

import inspect
from typing import Any

import numpy as np
from sb3_contrib import MaskablePPO
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.policies import BasePolicy

from sb3_marl.algos.rule_prior import RulePrior, RulePriorLearner
from sb3_marl.algos.teacher import SupervisorTeacher
from sb3_marl.checks import check_number
from sb3_marl.loading import SafeLoading
from sb3_marl.policies import CentralisedCriticPolicy

#: Policies of the maskable actor-critic learners: sb3-contrib's, plus the centralised critic
#: (``critic: centralised``, selected by the hyperparameters under this alias).
ACTOR_CRITIC_POLICIES: dict[str, type[BasePolicy]] = {
    **MaskablePPO.policy_aliases,
    CentralisedCriticPolicy.__name__: CentralisedCriticPolicy,
}


class MaskingLearner(SafeLoading):
    """What every learner of this module takes and saves: the ``action_masking`` switch, the
    ``safety_loss_coef`` of learning from the safety supervisor (see :class:`SupervisorTeacher`),
    and its class name (``algorithm_class`` in the zip's data, so that loading a model as another
    algorithm is refused by name: :func:`sb3_marl.runs.check_model_file`). Loading a model
    restores the saved values over these, and never unpickles (:class:`~sb3_marl.loading.SafeLoading`)."""

    def __init__(self, *args: Any, action_masking: bool = True, safety_loss_coef: float = 0.0, **kwargs: Any) -> None:
        self.algorithm_class = type(self).__name__
        self.action_masking = bool(action_masking)
        self.safety_loss_coef = check_safety_loss_coef(safety_loss_coef)
        super().__init__(*args, **kwargs)


def check_safety_loss_coef(coef: Any) -> float:
    """``safety_loss_coef`` as a float; a ValueError naming it unless a finite number >= 0."""
    return check_number("safety_loss_coef", coef, 0, expected="a finite number >= 0 (0: off)")


class ActionMaskingMixin(RulePriorLearner, SupervisorTeacher, MaskingLearner):
    """``action_masking`` switch of a maskable on-policy learner: sb3-contrib's masked rollouts
    and ``predict(..., action_masks=...)``, with masks only when ``action_masking`` is True; the
    supervisor as a teacher (:class:`SupervisorTeacher`) and the rule prior (:class:`RulePriorLearner`)."""

    action_masking: bool = True

    def collect_rollouts(
        self, env: Any, callback: Any, rollout_buffer: Any, n_rollout_steps: int, use_masking: bool = True
    ) -> bool:
        """sb3-contrib's masked rollout collection (``MaskablePPO.collect_rollouts``), recording the
        supervisor's interventions for the teacher's loss and the rule driver's labels for the prior's."""
        callback = self.with_recorder(callback, n_rollout_steps, env.num_envs)
        return MaskablePPO.collect_rollouts(
            self,  # type: ignore[arg-type]
            self.labelled(env, n_rollout_steps),
            callback,
            rollout_buffer,
            n_rollout_steps,
            use_masking=use_masking and self.action_masking,
        )

    def predict(
        self,
        observation: np.ndarray,
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
        action_masks: np.ndarray | None = None,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        """The policy's action; ``action_masks`` (batch, 5) bool restricts it to available actions
        (ignored when the model was trained with ``action_masking=False``)."""
        masks = action_masks if self.action_masking else None
        return self.policy.predict(observation, state, episode_start, deterministic, action_masks=masks)  # type: ignore[attr-defined]


def _with_action_masking(cls: type, base: type, teacher: bool = True, prior: bool = True) -> None:
    """Give ``cls`` the constructor signature of ``base`` plus ``action_masking`` (and, with
    ``teacher``, ``safety_loss_coef``; with ``prior``, the rule prior's keys), so that the zoo
    configs' validation (which reads constructor signatures) sees every argument."""
    signature = inspect.signature(base)
    extra = [inspect.Parameter("action_masking", inspect.Parameter.KEYWORD_ONLY, default=True, annotation=bool)]
    if teacher:
        extra.append(inspect.Parameter("safety_loss_coef", inspect.Parameter.KEYWORD_ONLY, default=0.0, annotation=float))
    if prior:
        extra += [
            inspect.Parameter(key, inspect.Parameter.KEYWORD_ONLY, default=value)
            for key, value in RulePrior().as_kwargs().items()
        ]
    cls.__signature__ = signature.replace(parameters=[*signature.parameters.values(), *extra])  # type: ignore[attr-defined]


def uses_action_masks(model: BaseAlgorithm) -> bool:
    """Whether ``model`` acts on action masks (a maskable learner with ``action_masking`` on)."""
    return bool(getattr(model, "action_masking", False))
