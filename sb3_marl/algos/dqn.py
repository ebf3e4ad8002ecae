"""MADQN: SB3's DQN with action masking, and the large-margin loss (DQfD) toward the safety
supervisor's actions or the rule driver's."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
import torch as th
import torch.nn.functional as F
from sb3_contrib.common.maskable.utils import get_action_masks
from stable_baselines3 import DQN
from stable_baselines3.common.type_aliases import GymEnv

from sb3_marl.algos.common.buffers import MaskedReplayBuffer
from sb3_marl.algos.common.loading import safe_load
from sb3_marl.algos.common.policies import clip_gradients
from sb3_marl.algos.common.rule_prior import RulePrior
from sb3_marl.algos.common.teacher import check_safety_loss_coef
from wrappers.step_arrays import step_arrays_of


def large_margin_loss(q_values: th.Tensor, labels: th.Tensor, margin: float) -> th.Tensor:
    """DQfD's large-margin loss ``max_a [Q(s, a) + margin·(a ≠ a_E)] - Q(s, a_E)`` averaged over the
    rows whose label a_E is >= 0 (0 without such rows): ``q_values`` (batch, n_actions), ``labels`` (batch,)."""
    chosen = labels >= 0
    if not bool(chosen.any()):
        return q_values.new_zeros(())
    q, labels = q_values[chosen], labels[chosen].long()
    margins = th.full_like(q, margin).scatter(1, labels[:, None], 0.0)
    return ((q + margins).max(dim=1).values - q.gather(1, labels[:, None]).squeeze(1)).mean()


class MaskableDQN(DQN):
    """SB3's DQN whose Q-values of unavailable meta-actions are excluded from the greedy action,
    from ε-greedy exploration (random actions among the available ones, also during warm-up) and
    from the bootstrap target ``max_a' Q_target(s', a')`` (over the actions available in s').

    With ``safety_loss_coef`` > 0 the safety supervisor is a teacher (as
    :func:`~sb3_marl.algos.common.teacher.safety_step` for the actor-critics): replayed transitions
    where it replaced the stored action add DQfD's
    large-margin loss ``safety_loss_coef * (max_a [Q(s, a) + margin·(a ≠ a_E)] - Q(s, a_E))``
    with a_E the executed action and margin :attr:`SAFETY_MARGIN`, so that the greedy action
    becomes the supervisor's.

    With ``prior: idm-mobil`` the rule driver is the starting point (as the actor-critics'
    :mod:`~sb3_marl.algos.common.rule_prior`, here in DQfD's way): for the first ``prior_warm_start``
    AV-steps it drives (its actions fill the replay buffer, in place of ε-greedy exploration), and
    every update adds ``w · `` the large-margin loss toward the rule action on the replayed next
    observations (the scenario labels each one, ``info["rule_action"]``), ``w`` falling from
    ``prior_coef`` to ``prior_coef_final`` over ``prior_decay_steps`` AV-steps after the warm start.

    :param action_masking: use the env's action masks (True) or SB3's DQN unchanged (False)
    :param safety_loss_coef: weight of the supervisor's large-margin loss (0: off)
    :param prior: ``idm-mobil`` or None (off), with ``prior_warm_start``, ``prior_coef``,
        ``prior_coef_final`` and ``prior_decay_steps`` (:class:`~sb3_marl.algos.common.rule_prior.RulePrior`)

    Other parameters: as SB3's ``DQN`` (the replay buffer is :class:`MaskedReplayBuffer`).
    """

    #: DQfD's margin of the teacher's action over the others (Hester et al. 2018: 0.8)
    SAFETY_MARGIN = 0.8
    known_classes: ClassVar[tuple[type, ...]] = (MaskedReplayBuffer,)
    load = safe_load

    def __init__(
        self,
        policy: Any,
        env: GymEnv | str,
        *args: Any,
        action_masking: bool = True,
        safety_loss_coef: float = 0.0,
        prior: str | None = None,
        prior_warm_start: int = 0,
        prior_coef: float = 1.0,
        prior_coef_final: float = 0.0,
        prior_decay_steps: int = 1,
        **kwargs: Any,
    ):
        settings = RulePrior(prior, prior_warm_start, prior_coef, prior_coef_final, prior_decay_steps)
        self.prior, self.prior_warm_start, self.prior_coef = settings.name, settings.warm_start, settings.coef
        self.prior_coef_final, self.prior_decay_steps = settings.coef_final, settings.decay_steps
        if (action_masking or safety_loss_coef or settings.active) and kwargs.get("replay_buffer_class") is None:
            kwargs["replay_buffer_class"] = MaskedReplayBuffer
        self.safety_loss_coef = check_safety_loss_coef(safety_loss_coef)
        self.algorithm_class = type(self).__name__  # saved: a model is loaded by its own class only
        self.action_masking = bool(action_masking)
        super().__init__(policy, env, *args, **kwargs)

    @property
    def rule_prior(self) -> RulePrior:
        return RulePrior(self.prior, self.prior_warm_start, self.prior_coef, self.prior_coef_final, self.prior_decay_steps)

    def predict(  # type: ignore[override]
        self,
        observation: np.ndarray,
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
        action_masks: np.ndarray | None = None,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        """ε-greedy (or greedy with ``deterministic``) action among the available ones of each row
        of ``action_masks`` (batch, n_actions); without masks, SB3's DQN ``predict``."""
        if action_masks is None or not self.action_masking:
            return super().predict(observation, state, episode_start, deterministic)
        masks = np.asarray(action_masks, dtype=bool).reshape(-1, int(self.action_space.n))  # type: ignore[attr-defined]
        if not deterministic and np.random.rand() < self.exploration_rate:
            return _random_available(masks), state
        obs_tensor, vectorized = self.policy.obs_to_tensor(observation)
        with th.no_grad():
            q_values = self.q_net(obs_tensor).cpu().numpy()
        actions = np.where(masks, q_values, -np.inf).argmax(axis=1)
        return (actions if vectorized else actions[0]), state

    def _sample_action(self, learning_starts: int, action_noise: Any = None, n_envs: int = 1) -> tuple[np.ndarray, np.ndarray]:
        assert self.env is not None and self._last_obs is not None, "the DQN collects on its env"
        if self.prior is not None and self.num_timesteps < self.prior_warm_start:  # the rule driver drives
            actions = np.asarray(self.env.env_method("rule_actions"), dtype=np.int64)
            return actions, actions
        if not self.action_masking:
            return super()._sample_action(learning_starts, action_noise, n_envs)
        masks = get_action_masks(self.env)
        if self.num_timesteps < learning_starts:
            actions = _random_available(masks)
        else:
            actions, _ = self.predict(self._last_obs, deterministic=False, action_masks=masks)  # type: ignore[arg-type]
        return actions, actions

    def _store_transition(self, replay_buffer: Any, *args: Any, **kwargs: Any) -> None:
        """SB3's, with what the VecEnv's step arrays say of the transition (the next masks, the
        supervisor's and the rule driver's actions) kept beside it in a :class:`MaskedReplayBuffer`."""
        if isinstance(replay_buffer, MaskedReplayBuffer):
            replay_buffer.record(step_arrays_of(self.env))
        super()._store_transition(replay_buffer, *args, **kwargs)

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:
        """SB3's ``DQN.train`` with the bootstrap target's max over the available next actions."""
        prior_weight = self.rule_prior.weight(self.num_timesteps)
        if not self.action_masking and not self.safety_loss_coef and not prior_weight:
            return super().train(gradient_steps, batch_size)
        self.policy.set_training_mode(True)
        self._update_learning_rate(self.policy.optimizer)
        losses, safety_losses, prior_losses = [], [], []
        assert self.replay_buffer is not None
        for _ in range(gradient_steps):
            replay_data: Any = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)
            discounts = replay_data.discounts if replay_data.discounts is not None else self.gamma
            with th.no_grad():
                next_q_values = self.q_net_target(replay_data.next_observations)
                if self.action_masking:
                    next_q_values = next_q_values.masked_fill(~replay_data.next_action_masks, -th.inf)  # the change
                next_q_values = next_q_values.max(dim=1).values.reshape(-1, 1)
                target_q_values = replay_data.rewards + (1 - replay_data.dones) * discounts * next_q_values
            q_values = self.q_net(replay_data.observations)
            current_q_values = th.gather(q_values, dim=1, index=replay_data.actions.long())
            loss = F.smooth_l1_loss(current_q_values, target_q_values)
            losses.append(loss.item())
            if self.safety_loss_coef:
                safety_loss = large_margin_loss(q_values, replay_data.executed_actions, self.SAFETY_MARGIN)
                safety_losses.append(safety_loss.item())
                loss = loss + self.safety_loss_coef * safety_loss
            if prior_weight:
                next_q = self.q_net(replay_data.next_observations)
                prior_loss = large_margin_loss(next_q, replay_data.next_rule_actions, self.SAFETY_MARGIN)
                prior_losses.append(prior_loss.item())
                loss = loss + prior_weight * prior_loss
            self.policy.optimizer.zero_grad()
            loss.backward()
            clip_gradients(self.policy.optimizer, self.max_grad_norm)
            self.policy.optimizer.step()
        self._n_updates += gradient_steps
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        self.logger.record("train/loss", np.mean(losses))
        if safety_losses:
            self.logger.record("train/safety_loss", np.mean(safety_losses))
        if prior_losses:
            self.logger.record("train/prior_loss", np.mean(prior_losses))
            self.logger.record("train/prior_coef", prior_weight)


def _random_available(masks: np.ndarray) -> np.ndarray:
    """One uniformly random available action per row of ``masks`` (batch, n_actions) bool,
    drawn with numpy's global generator as SB3's DQN exploration (seeded by ``set_random_seed``)."""
    scores = np.random.random_sample(masks.shape)
    return np.where(masks, scores, -1.0).argmax(axis=1)
