"""The learners' buffers: MADQN's replay buffer with the next states' action masks and the
supervisor's actions, and MA2C's per-AV-slot minibatches of a rollout."""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
import torch as th
from gymnasium import spaces
from sb3_contrib.common.maskable.buffers import MaskableDictRolloutBuffer, MaskableRolloutBuffer
from stable_baselines3.common.buffers import ReplayBuffer

from sb3_marl.algos.common.teacher import executed_labels
from wrappers.step_arrays import StepArrays


class MaskedReplayBufferSamples(NamedTuple):
    """SB3's ``ReplayBufferSamples`` plus the action mask of each next observation, the action
    the safety supervisor executed in place of the stored one (-1: it did not intervene) and the
    rule driver's action for the next observation (-1: none, or the AV has left the road)."""

    observations: th.Tensor
    actions: th.Tensor
    next_observations: th.Tensor
    dones: th.Tensor
    rewards: th.Tensor
    next_action_masks: th.Tensor
    executed_actions: th.Tensor
    next_rule_actions: th.Tensor
    discounts: th.Tensor | None = None


class MaskedReplayBuffer(ReplayBuffer):
    """SB3's ``ReplayBuffer`` that also keeps, from the VecEnv's step arrays (:meth:`record`), the
    action mask of every next observation (after an episode end, of the terminal observation), the
    action the safety supervisor executed where it replaced the stored one (-1 elsewhere), and the
    rule driver's action for each next observation (-1 where the AV has left the road)."""

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Space,
        action_space: spaces.Discrete,
        device: th.device | str = "auto",
        n_envs: int = 1,
        optimize_memory_usage: bool = False,
        handle_timeout_termination: bool = True,
    ) -> None:
        if optimize_memory_usage:
            raise ValueError("MaskedReplayBuffer does not support optimize_memory_usage=True.")
        super().__init__(buffer_size, observation_space, action_space, device, n_envs, False, handle_timeout_termination)
        self.next_action_masks = np.ones((self.buffer_size, self.n_envs, int(action_space.n)), dtype=bool)
        self.executed_actions = np.full((self.buffer_size, self.n_envs), -1, dtype=np.int64)
        self.next_rule_actions = np.full((self.buffer_size, self.n_envs), -1, dtype=np.int64)

    def record(self, arrays: StepArrays | None) -> None:
        """Keep what a step's arrays say of the transition that :meth:`add` stores next (None, a
        VecEnv without them: every action available, no supervisor or rule action)."""
        self.executed_actions[self.pos] = executed_labels(arrays, self.n_envs)
        if arrays is None:
            self.next_action_masks[self.pos], self.next_rule_actions[self.pos] = True, -1
            return
        self.next_action_masks[self.pos] = arrays.action_mask
        self.next_rule_actions[self.pos] = np.where(arrays.exited, -1, arrays.rule_action)

    def _get_samples(self, batch_inds: np.ndarray, env: Any = None) -> MaskedReplayBufferSamples:  # type: ignore[override]
        """SB3's ``ReplayBuffer._get_samples`` (without the memory-optimised layout) plus the masks."""
        env_indices = np.random.randint(0, high=self.n_envs, size=(len(batch_inds),))
        data = (
            self._normalize_obs(self.observations[batch_inds, env_indices, :], env),
            self.actions[batch_inds, env_indices, :],
            self._normalize_obs(self.next_observations[batch_inds, env_indices, :], env),
            (self.dones[batch_inds, env_indices] * (1 - self.timeouts[batch_inds, env_indices])).reshape(-1, 1),
            self._normalize_reward(self.rewards[batch_inds, env_indices].reshape(-1, 1), env),
            self.next_action_masks[batch_inds, env_indices, :],
            self.executed_actions[batch_inds, env_indices],
            self.next_rule_actions[batch_inds, env_indices],
        )
        return MaskedReplayBufferSamples(*tuple(map(self.to_torch, data)))


class PerAgentRolloutBuffer(MaskableRolloutBuffer):
    """sb3-contrib's maskable rollout buffer under the name MA2C models saved before 2026-12-06
    give it (their per-slot minibatches are :meth:`~sb3_marl.algos.a2c.MaskableA2C._minibatches`
    now); kept so those models load."""


class PerAgentDictRolloutBuffer(MaskableDictRolloutBuffer):
    """The same on Dict observations (``critic: centralised``)."""
