"""The safety supervisor as a teacher of the learners (``safety_loss_coef`` > 0): the labels of
its interventions, their recording during rollouts, and the actor-critics' auxiliary step."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch as th

from sb3_marl.algos.common.policies import clip_gradients
from sb3_marl.common.checks import check_number
from wrappers.step_arrays import StepArrays


def executed_labels(arrays: StepArrays | None, n_envs: int) -> np.ndarray:
    """Per VecEnv slot of one step: the action the safety supervisor executed where it replaced the
    proposal of an AV still on the road, -1 elsewhere (the labels of the teachers' losses; all -1
    without ``arrays``, a VecEnv that does not report them)."""
    if arrays is None:
        return np.full(n_envs, -1, dtype=np.int64)
    return np.where(arrays.intervened & ~arrays.exited, arrays.executed_action, -1).astype(np.int64)


def safety_loss(policy: Any, observations: Any, action_masks: np.ndarray | None, executed: th.Tensor) -> th.Tensor:
    """``-log π(executed | s)`` averaged over the given (intervened) samples."""
    distribution = policy.get_distribution(observations, action_masks=action_masks)
    return -distribution.log_prob(executed).mean()


def safety_step(model: Any, executed: np.ndarray) -> float:
    """The teacher's step (``safety_loss_coef`` > 0): after each update, one more optimiser step
    of ``model`` on ``safety_loss_coef * mean(-log π(executed | s))`` over the rollout buffer's
    samples whose entry of ``executed`` ((n_steps, n_envs), -1: no intervention) names the
    action the supervisor executed in place of the policy's proposal; the policy learns to propose
    what the supervisor would have done, so that it stays safe without it. Returns the loss before
    the step (0 without intervened samples: the policy is left unchanged). Logged as
    ``train/safety_loss`` and ``train/intervened_share``."""
    buffer = model.rollout_buffer
    labels = executed.swapaxes(0, 1).reshape(-1) if buffer.generator_ready else executed.reshape(-1)
    observations = _flat_samples(buffer.observations, buffer.obs_shape, len(labels))
    masks = buffer.action_masks.reshape(len(labels), -1) if model.action_masking else None
    chosen = np.flatnonzero(labels >= 0)
    model.logger.record("train/intervened_share", chosen.size / max(len(labels), 1))
    if chosen.size == 0:
        model.logger.record("train/safety_loss", 0.0)
        return 0.0
    policy = model.policy
    policy.set_training_mode(True)
    loss = safety_loss(
        policy,
        policy.obs_to_tensor(select_rows(observations, chosen))[0],
        None if masks is None else masks[chosen],
        th.as_tensor(labels[chosen], device=policy.device),
    )
    policy.optimizer.zero_grad()
    (model.safety_loss_coef * loss).backward()
    clip_gradients(policy.optimizer, model.max_grad_norm)
    policy.optimizer.step()
    model.logger.record("train/safety_loss", float(loss.item()))
    return float(loss.item())


#: The largest weight of an auxiliary loss term (the teacher's, the rule prior's): far beyond any
#: useful one, and far below the weights whose gradients overflow to NaN.
MAX_LOSS_WEIGHT = 1_000.0


def check_safety_loss_coef(coef: Any) -> float:
    """``safety_loss_coef`` as a float; a ValueError naming it unless a number in [0, 1000]."""
    return check_number("safety_loss_coef", coef, 0, MAX_LOSS_WEIGHT, expected="a number in [0, 1000] (0: off)")


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
