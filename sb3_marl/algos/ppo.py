"""MAPPO: sb3-contrib's ``MaskablePPO`` with the ``action_masking`` switch, whose update (ours, the
clipped surrogate of ``MaskablePPO.train``) also takes the rule prior's term and the supervisor
teacher's step; MA2C (:mod:`sb3_marl.algos.a2c`) shares its set-up, with A2C's update."""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterator
from typing import ClassVar

import numpy as np
import torch as th
import torch.nn.functional as F
from sb3_contrib import MaskablePPO
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.utils import explained_variance

from sb3_marl.algos.common.base import ACTOR_CRITIC_POLICIES, MaskableOnPolicy
from sb3_marl.algos.common.policies import clip_gradients


class MaskableActorCritic(MaskableOnPolicy, MaskablePPO):  # type: ignore[misc]  # predict: sb3-contrib's, typed wider
    """sb3-contrib's ``MaskablePPO`` with the ``action_masking`` switch (see the module doc), whose
    update adds the rule prior's term to each minibatch's loss (same loss, same optimiser step),
    then takes the supervisor teacher's step."""

    def _minibatches(self) -> Iterator[np.ndarray]:
        """Indices of the flattened (slot-major) rollout buffer, one array per minibatch, drawn from
        numpy's global generator in the same order as sb3-contrib's ``get`` (so seeded runs repeat
        those of the buffers' own generators)."""
        buffer = self.rollout_buffer
        steps, n_envs = buffer.buffer_size, buffer.n_envs
        order = np.random.permutation(steps * n_envs)
        if not buffer.generator_ready:  # sb3-contrib flattens the arrays slot-major on first use
            state = np.random.get_state()
            next(buffer.get(None))
            np.random.set_state(state)  # the flattening's own permutation is not one of ours
        size = self.batch_size or steps * n_envs
        for start in range(0, steps * n_envs, size):
            yield order[start : start + size]

    def train(self) -> None:
        """``MaskablePPO.train`` (clipped surrogate, optionally clipped value loss, entropy bonus,
        early stop at ``target_kl``) plus ``w · prior_loss`` (:meth:`prior_term`)."""
        self.policy.set_training_mode(True)
        self._update_learning_rate(self.policy.optimizer)
        clip_range = self.clip_range(self._current_progress_remaining)  # type: ignore[operator]
        clip_range_vf = None if self.clip_range_vf is None else self.clip_range_vf(self._current_progress_remaining)  # type: ignore[operator]
        logs: dict[str, list] = defaultdict(list)
        for _ in range(self.n_epochs):
            approx_kl_divs = []
            for indices in self._minibatches():
                data = self.rollout_buffer._get_samples(indices)
                values, log_prob, entropy = self.policy.evaluate_actions(
                    data.observations, data.actions.long().flatten(), action_masks=data.action_masks
                )
                values = values.flatten()
                advantages = data.advantages
                if self.normalize_advantage:
                    advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
                ratio = th.exp(log_prob - data.old_log_prob)
                policy_loss = -th.min(advantages * ratio, advantages * th.clamp(ratio, 1 - clip_range, 1 + clip_range)).mean()
                if clip_range_vf is not None:
                    values = data.old_values + th.clamp(values - data.old_values, -clip_range_vf, clip_range_vf)
                value_loss = F.mse_loss(data.returns, values)
                entropy_loss = -th.mean(-log_prob) if entropy is None else -th.mean(entropy)
                loss = policy_loss + self.ent_coef * entropy_loss + self.vf_coef * value_loss
                loss = loss + self.prior_term(data.observations, data.action_masks, indices, logs)
                logs["policy_gradient_loss"].append(policy_loss.item())
                logs["value_loss"].append(value_loss.item())
                logs["entropy_loss"].append(entropy_loss.item())
                logs["clip_fraction"].append(th.mean((th.abs(ratio - 1) > clip_range).float()).item())
                with th.no_grad():
                    log_ratio = log_prob - data.old_log_prob
                    approx_kl_divs.append(th.mean((th.exp(log_ratio) - 1) - log_ratio).item())
                if self.target_kl is not None and approx_kl_divs[-1] > 1.5 * self.target_kl:
                    break
                self.policy.optimizer.zero_grad()
                loss.backward()
                clip_gradients(self.policy.optimizer, self.max_grad_norm)
                self.policy.optimizer.step()
            self._n_updates += 1
            logs["approx_kl"] += approx_kl_divs
            if self.target_kl is not None and approx_kl_divs and approx_kl_divs[-1] > 1.5 * self.target_kl:
                break
        for key, entries in logs.items():
            self.logger.record(f"train/{key}", float(np.mean(entries)))
        buffer = self.rollout_buffer
        self.logger.record("train/loss", loss.item())
        self.logger.record("train/explained_variance", explained_variance(buffer.values.flatten(), buffer.returns.flatten()))
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        self.logger.record("train/clip_range", clip_range)
        if clip_range_vf is not None:
            self.logger.record("train/clip_range_vf", clip_range_vf)
        executed = self.rollout_extras.executed
        if self.safety_loss_coef > 0 and executed is not None:  # the teacher's step
            self.safety_step(executed)


class MaskedPPO(MaskableActorCritic):
    """sb3-contrib's ``MaskablePPO`` with the ``action_masking`` switch (see the module doc)."""

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = ACTOR_CRITIC_POLICIES
