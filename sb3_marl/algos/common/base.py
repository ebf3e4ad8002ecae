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
from stable_baselines3.common.policies import BasePolicy

from sb3_marl.algos.common.loading import SafeLoading
from sb3_marl.algos.common.policies import CentralisedCriticPolicy
from sb3_marl.algos.common.rule_prior import RulePriorLearner

#: Policies of the maskable actor-critic learners: sb3-contrib's, plus the centralised critic
#: (``critic: centralised``, selected by the hyperparameters under this alias).
ACTOR_CRITIC_POLICIES: dict[str, type[BasePolicy]] = {
    **MaskablePPO.policy_aliases,
    CentralisedCriticPolicy.__name__: CentralisedCriticPolicy,
}


class MaskingLearner(SafeLoading):
    """What every learner of this module takes and saves: the ``action_masking`` switch and its
    class name (``algorithm_class`` in the zip's data, so that loading a model as another
    algorithm is refused by name: :func:`sb3_marl.runs.folders.check_model_file`). Loading a model
    restores the saved values over these, and never unpickles (:class:`~sb3_marl.algos.common.loading.SafeLoading`)."""

    def __init__(self, *args: Any, action_masking: bool = True, **kwargs: Any) -> None:
        self.algorithm_class = type(self).__name__
        self.action_masking = bool(action_masking)
        super().__init__(*args, **kwargs)


def hyperparameters(cls: type) -> dict[str, inspect.Parameter]:
    """The keyword arguments a learner class takes: those of its own ``__init__`` and of each class
    up its MRO that the arguments are passed on to (``**kwargs``), down to the first that takes no
    more (SB3's algorithm)."""
    found: dict[str, inspect.Parameter] = {}
    for klass in cls.__mro__:
        if "__init__" not in vars(klass):
            continue
        parameters = list(inspect.signature(klass.__init__).parameters.values())[1:]  # type: ignore[misc]
        skipped = (inspect.Parameter.VAR_POSITIONAL, inspect.Parameter.VAR_KEYWORD)
        found.update({p.name: p for p in parameters if p.kind not in skipped and p.name not in found})
        if all(p.kind != inspect.Parameter.VAR_KEYWORD for p in parameters):
            break
    return found


class ActionMaskingMixin(RulePriorLearner, MaskingLearner):  # type: ignore[misc]  # SafeLoading.load: SB3's plus trust_remote_code
    """``action_masking`` switch of a maskable on-policy learner: sb3-contrib's masked rollouts
    and ``predict(..., action_masks=...)``, with masks only when ``action_masking`` is True, and
    the rule prior (:class:`RulePriorLearner`)."""

    action_masking: bool = True

    def rollout_callback(self, callback: Any, n_rollout_steps: int, n_envs: int) -> Any:
        """The callback of a rollout (the teacher's adds its recorder: :class:`SupervisorTeacher`)."""
        return callback

    def collect_rollouts(
        self, env: Any, callback: Any, rollout_buffer: Any, n_rollout_steps: int, use_masking: bool = True
    ) -> bool:
        """sb3-contrib's masked rollout collection (``MaskablePPO.collect_rollouts``), recording the
        supervisor's interventions for the teacher's loss and the rule driver's labels for the prior's."""
        callback = self.rollout_callback(callback, n_rollout_steps, env.num_envs)
        return MaskablePPO.collect_rollouts(
            self,  # type: ignore[arg-type]
            self.labelled(env, n_rollout_steps),
            callback,
            rollout_buffer,
            n_rollout_steps,
            use_masking=use_masking and self.action_masking,
        )

    def predict(  # type: ignore[override]  # plus sb3-contrib's action_masks
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
        return self.policy.predict(observation, state, episode_start, deterministic, action_masks=masks)  # type: ignore[call-arg]  # a maskable policy
