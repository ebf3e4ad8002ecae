"""The safety supervisor as a teacher of the learners (``safety_loss_coef`` > 0): the labels of
its interventions, their recording during rollouts, and the actor-critics' auxiliary step."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
import torch as th
from stable_baselines3.common.callbacks import BaseCallback, CallbackList

from sb3_marl.common.checks import check_number

if TYPE_CHECKING:  # the host the mixins below are written for (at run time: their own MRO)
    from sb3_contrib import MaskablePPO as _OnPolicyHost
else:
    _OnPolicyHost = object


def executed_labels(infos: list[dict[str, Any]]) -> list[int]:
    """Per VecEnv slot of one step: the action the safety supervisor executed where it replaced the
    proposal of an AV still on the road, -1 elsewhere (the labels of the teachers' losses)."""
    return [
        int(info["executed_action"]) if info.get("intervened", False) and not info.get("exited", False) else -1
        for info in infos
    ]


class InterventionRecorder(BaseCallback):
    """Records, per rollout step and VecEnv slot, the action the safety supervisor executed where
    it replaced the policy's proposal (``info["intervened"]``), -1 elsewhere: the labels of
    :class:`SupervisorTeacher`'s loss. Arrays are ``(n_steps, n_envs)``, as the rollout buffer's."""

    def __init__(self, n_steps: int, n_envs: int) -> None:
        super().__init__()
        self.executed = np.full((n_steps, n_envs), -1, dtype=np.int64)
        self.position = 0

    def _on_rollout_start(self) -> None:
        self.executed[:] = -1
        self.position = 0

    def _on_step(self) -> bool:
        if self.position < len(self.executed):
            self.executed[self.position] = executed_labels(self.locals["infos"])
        self.position += 1
        return True


class _InitialisedCallbacks(CallbackList):
    """A CallbackList of callbacks already initialised (initialising it does not redo theirs)."""

    def _init_callback(self) -> None:
        pass


class SupervisorTeacher(_OnPolicyHost):
    """The safety supervisor as a teacher of an on-policy maskable learner (``safety_loss_coef`` > 0).

    After each update, one more optimiser step on the auxiliary loss
    ``safety_loss_coef * mean(-log π(executed | s))`` over the rollout's steps where the supervisor
    replaced the policy's proposal (the action it executed is the label): the policy learns to
    propose what the supervisor would have done, so that it stays safe without it. Steps without
    an intervention contribute nothing; a rollout without any leaves the policy unchanged.
    Logged as ``train/safety_loss`` and ``train/intervened_share``.
    """

    safety_loss_coef: float = 0.0
    action_masking: bool  # the host's (MaskingLearner)
    _recorder: InterventionRecorder | None = None

    def __init__(self, *args: Any, safety_loss_coef: float = 0.0, **kwargs: Any) -> None:
        self.safety_loss_coef = check_safety_loss_coef(safety_loss_coef)
        super().__init__(*args, **kwargs)

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "_recorder"]

    def rollout_callback(self, callback: Any, n_rollout_steps: int, n_envs: int) -> Any:
        """``callback`` plus the intervention recorder when the teacher is on."""
        if self.safety_loss_coef <= 0:
            return callback
        if self._recorder is None or self._recorder.executed.shape != (n_rollout_steps, n_envs):
            self._recorder = InterventionRecorder(n_rollout_steps, n_envs)
            self._recorder.init_callback(self)
        together = _InitialisedCallbacks([callback, self._recorder])
        together.init_callback(self)
        return together

    def safety_loss(
        self, observations: th.Tensor | dict[str, th.Tensor], action_masks: np.ndarray | None, executed: th.Tensor
    ) -> th.Tensor:
        """``-log π(executed | s)`` averaged over the given (intervened) samples."""
        distribution = self.policy.get_distribution(observations, action_masks=action_masks)
        return -distribution.log_prob(executed).mean()

    def safety_step(self, executed: np.ndarray) -> float:
        """One optimiser step on the auxiliary loss over the rollout buffer's samples whose entry
        of ``executed`` ((n_steps, n_envs), -1: no intervention) names the supervisor's action;
        returns the loss before the step (0 without intervened samples)."""
        buffer = self.rollout_buffer
        labels = executed.swapaxes(0, 1).reshape(-1) if buffer.generator_ready else executed.reshape(-1)
        observations = _flat_samples(buffer.observations, buffer.obs_shape, len(labels))
        masks = buffer.action_masks.reshape(len(labels), -1) if self.action_masking else None
        chosen = np.flatnonzero(labels >= 0)
        self.logger.record("train/intervened_share", chosen.size / max(len(labels), 1))
        if chosen.size == 0:
            self.logger.record("train/safety_loss", 0.0)
            return 0.0
        policy = self.policy
        policy.set_training_mode(True)
        loss = self.safety_loss(
            policy.obs_to_tensor(select_rows(observations, chosen))[0],
            None if masks is None else masks[chosen],
            th.as_tensor(labels[chosen], device=policy.device),
        )
        policy.optimizer.zero_grad()
        (self.safety_loss_coef * loss).backward()
        th.nn.utils.clip_grad_norm_(policy.parameters(), self.max_grad_norm)
        policy.optimizer.step()
        self.logger.record("train/safety_loss", float(loss.item()))
        return float(loss.item())


def check_safety_loss_coef(coef: Any) -> float:
    """``safety_loss_coef`` as a float; a ValueError naming it unless a finite number >= 0."""
    return check_number("safety_loss_coef", coef, 0, expected="a finite number >= 0 (0: off)")


def _flat_samples(observations: Any, obs_shape: Any, n: int) -> Any:
    """A rollout buffer's observations (an array, or a dict of arrays) as ``n`` samples."""
    if isinstance(observations, dict):
        return {key: value.reshape(n, *obs_shape[key]) for key, value in observations.items()}
    return observations.reshape(n, *obs_shape)


def select_rows(observations: Any, rows: np.ndarray) -> Any:
    """The ``rows`` of observations (an array, or a dict of arrays)."""
    if isinstance(observations, dict):
        return {key: value[rows] for key, value in observations.items()}
    return observations[rows]
