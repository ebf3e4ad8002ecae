"""Learners that never sample an unavailable meta-action, as the authors' MA2C (masked logits).

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

All take ``action_masking`` (default True): False trains and acts without masks (the unmasked
learner of the ablation) with the same network. The setting is saved with the model, and
``predict(obs, action_masks=...)`` takes masks exactly as sb3-contrib's maskable algorithms do.
"""

from __future__ import annotations

import inspect
import math
from typing import Any, ClassVar, NamedTuple

import numpy as np
import torch as th
import torch.nn.functional as F
from gymnasium import spaces
from sb3_contrib import MaskablePPO
from sb3_contrib.common.maskable.buffers import MaskableRolloutBuffer
from sb3_contrib.common.maskable.utils import get_action_masks
from stable_baselines3 import DQN
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.buffers import ReplayBuffer, RolloutBuffer
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, Schedule

from sb3_marl.algos.acktr import ACKTR


class MaskingLearner:
    """What every learner of this module takes and saves: the ``action_masking`` switch, and its
    class name (``algorithm_class`` in the zip's data, so that loading a model as another
    algorithm is refused by name: :func:`sb3_marl.runs.check_model_file`). Loading a model
    restores the saved values over these."""

    def __init__(self, *args: Any, action_masking: bool = True, **kwargs: Any) -> None:
        self.algorithm_class = type(self).__name__
        self.action_masking = bool(action_masking)
        super().__init__(*args, **kwargs)


class ActionMaskingMixin(MaskingLearner):
    """``action_masking`` switch of a maskable on-policy learner: sb3-contrib's masked rollouts
    and ``predict(..., action_masks=...)``, with masks only when ``action_masking`` is True."""

    action_masking: bool = True

    def collect_rollouts(self, env: Any, callback: Any, rollout_buffer: Any, n_rollout_steps: int,
                         use_masking: bool = True) -> bool:
        """sb3-contrib's masked rollout collection (``MaskablePPO.collect_rollouts``)."""
        return MaskablePPO.collect_rollouts(
            self, env, callback, rollout_buffer, n_rollout_steps, use_masking=use_masking and self.action_masking
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
        return self.policy.predict(observation, state, episode_start, deterministic, action_masks=masks)


def _with_action_masking(cls: type, base: type) -> None:
    """Give ``cls`` the constructor signature of ``base`` plus ``action_masking``, so that the zoo
    configs' validation (which reads constructor signatures) sees every argument."""
    signature = inspect.signature(base)
    cls.__signature__ = signature.replace(parameters=[
        *signature.parameters.values(),
        inspect.Parameter("action_masking", inspect.Parameter.KEYWORD_ONLY, default=True, annotation=bool),
    ])


class MaskedPPO(ActionMaskingMixin, MaskablePPO):
    """sb3-contrib's ``MaskablePPO`` with the ``action_masking`` switch (see the module doc)."""


class MaskableACKTR(ActionMaskingMixin, ACKTR):
    """Our :class:`~sb3_marl.algos.acktr.ACKTR` on sb3-contrib's maskable policy, rollout buffer and
    masked rollouts (see the module doc); ACKTR's update evaluates the actions under their masks."""

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = MaskablePPO.policy_aliases

    def _setup_model(self) -> None:
        """As ``MaskablePPO._setup_model`` (maskable policy and rollout buffer), then K-FAC."""
        self._setup_lr_schedule()
        self.set_random_seed(self.seed)
        self.policy = self.policy_class(
            self.observation_space, self.action_space, self.lr_schedule, **self.policy_kwargs
        ).to(self.device)
        self.rollout_buffer = MaskableRolloutBuffer(
            self.n_steps, self.observation_space, self.action_space, self.device,
            gamma=self.gamma, gae_lambda=self.gae_lambda, n_envs=self.n_envs,
        )
        self._setup_optimizer()


class MaskedReplayBufferSamples(NamedTuple):
    """SB3's ``ReplayBufferSamples`` plus the action mask of each next observation."""

    observations: th.Tensor
    actions: th.Tensor
    next_observations: th.Tensor
    dones: th.Tensor
    rewards: th.Tensor
    next_action_masks: th.Tensor
    discounts: th.Tensor | None = None


class MaskedReplayBuffer(ReplayBuffer):
    """SB3's ``ReplayBuffer`` that also keeps the action mask of every next observation, taken
    from the step infos' ``action_mask`` (the scenario reports the mask of the observation it
    returns; after an episode end, of the terminal observation). Without one: all available."""

    def __init__(self, buffer_size: int, observation_space: spaces.Space, action_space: spaces.Discrete,
                 device: th.device | str = "auto", n_envs: int = 1, optimize_memory_usage: bool = False,
                 handle_timeout_termination: bool = True) -> None:
        if optimize_memory_usage:
            raise ValueError("MaskedReplayBuffer does not support optimize_memory_usage=True.")
        super().__init__(buffer_size, observation_space, action_space, device, n_envs, False, handle_timeout_termination)
        self.next_action_masks = np.ones((self.buffer_size, self.n_envs, int(action_space.n)), dtype=bool)

    def add(self, obs: np.ndarray, next_obs: np.ndarray, action: np.ndarray, reward: np.ndarray,
            done: np.ndarray, infos: list[dict[str, Any]]) -> None:
        self.next_action_masks[self.pos] = [info.get("action_mask", True) for info in infos]
        super().add(obs, next_obs, action, reward, done, infos)

    def _get_samples(self, batch_inds: np.ndarray, env: Any = None) -> MaskedReplayBufferSamples:
        """SB3's ``ReplayBuffer._get_samples`` (without the memory-optimised layout) plus the masks."""
        env_indices = np.random.randint(0, high=self.n_envs, size=(len(batch_inds),))
        data = (
            self._normalize_obs(self.observations[batch_inds, env_indices, :], env),
            self.actions[batch_inds, env_indices, :],
            self._normalize_obs(self.next_observations[batch_inds, env_indices, :], env),
            (self.dones[batch_inds, env_indices] * (1 - self.timeouts[batch_inds, env_indices])).reshape(-1, 1),
            self._normalize_reward(self.rewards[batch_inds, env_indices].reshape(-1, 1), env),
            self.next_action_masks[batch_inds, env_indices, :],
        )
        return MaskedReplayBufferSamples(*tuple(map(self.to_torch, data)))


class MaskableDQN(MaskingLearner, DQN):
    """SB3's DQN whose Q-values of unavailable meta-actions are excluded from the greedy action,
    from ε-greedy exploration (random actions among the available ones, also during warm-up) and
    from the bootstrap target ``max_a' Q_target(s', a')`` (over the actions available in s').

    :param action_masking: use the env's action masks (True) or SB3's DQN unchanged (False)

    Other parameters: as SB3's ``DQN`` (the replay buffer is :class:`MaskedReplayBuffer`).
    """

    def __init__(self, policy: Any, env: GymEnv | str | None, *args: Any, action_masking: bool = True, **kwargs: Any):
        if action_masking and kwargs.get("replay_buffer_class") is None:
            kwargs["replay_buffer_class"] = MaskedReplayBuffer
        super().__init__(policy, env, *args, action_masking=action_masking, **kwargs)

    def predict(
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
        masks = np.asarray(action_masks, dtype=bool).reshape(-1, int(self.action_space.n))
        if not deterministic and np.random.rand() < self.exploration_rate:
            return _random_available(masks), state
        obs_tensor, vectorized = self.policy.obs_to_tensor(observation)
        with th.no_grad():
            q_values = self.q_net(obs_tensor).cpu().numpy()
        actions = np.where(masks, q_values, -np.inf).argmax(axis=1)
        return (actions if vectorized else actions[0]), state

    def _sample_action(self, learning_starts: int, action_noise: Any = None, n_envs: int = 1) -> tuple[np.ndarray, np.ndarray]:
        if not self.action_masking:
            return super()._sample_action(learning_starts, action_noise, n_envs)
        masks = get_action_masks(self.env)
        if self.num_timesteps < learning_starts:
            actions = _random_available(masks)
        else:
            actions, _ = self.predict(self._last_obs, deterministic=False, action_masks=masks)
        return actions, actions

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:
        """SB3's ``DQN.train`` with the bootstrap target's max over the available next actions."""
        if not self.action_masking:
            return super().train(gradient_steps, batch_size)
        self.policy.set_training_mode(True)
        self._update_learning_rate(self.policy.optimizer)
        losses = []
        for _ in range(gradient_steps):
            replay_data = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)
            discounts = replay_data.discounts if replay_data.discounts is not None else self.gamma
            with th.no_grad():
                next_q_values = self.q_net_target(replay_data.next_observations)
                next_q_values = next_q_values.masked_fill(~replay_data.next_action_masks, -th.inf)  # the change
                next_q_values = next_q_values.max(dim=1).values.reshape(-1, 1)
                target_q_values = replay_data.rewards + (1 - replay_data.dones) * discounts * next_q_values
            current_q_values = th.gather(self.q_net(replay_data.observations), dim=1, index=replay_data.actions.long())
            loss = F.smooth_l1_loss(current_q_values, target_q_values)
            losses.append(loss.item())
            self.policy.optimizer.zero_grad()
            loss.backward()
            th.nn.utils.clip_grad_norm_(self.policy.parameters(), self.max_grad_norm)
            self.policy.optimizer.step()
        self._n_updates += gradient_steps
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        self.logger.record("train/loss", np.mean(losses))


def _random_available(masks: np.ndarray) -> np.ndarray:
    """One uniformly random available action per row of ``masks`` (batch, n_actions) bool,
    drawn with numpy's global generator as SB3's DQN exploration (seeded by ``set_random_seed``)."""
    scores = np.random.random_sample(masks.shape)
    return np.where(masks, scores, -1.0).argmax(axis=1)


_with_action_masking(MaskedPPO, MaskablePPO)
_with_action_masking(MaskableACKTR, ACKTR)
_with_action_masking(MaskableDQN, DQN)


class PerAgentRolloutBuffer(MaskableRolloutBuffer):
    """sb3-contrib's maskable rollout buffer whose minibatches are the VecEnv slots: each yields
    one AV slot's ``n_steps`` consecutive transitions, the slots in random order (the authors' MA2C
    takes one optimiser step per AV on that AV's transitions)."""

    def get(self, batch_size: int | None = None) -> Any:
        if not self.generator_ready:
            next(super().get(None))  # sb3-contrib flattens the arrays slot-major on first use
        for slot in np.random.permutation(self.n_envs):
            yield self._get_samples(np.arange(slot * self.buffer_size, (slot + 1) * self.buffer_size))


class MaskableA2C(ActionMaskingMixin, MaskablePPO):
    """A2C (SB3's arguments and defaults) with invalid-action masking (see the module doc).

    :param action_masking: sample only available meta-actions (the authors' MA2C) or all of them
    :param rms_prop_eps: RMSprop epsilon (with ``use_rms_prop``; RMSprop alpha 0.99 as SB3's A2C)
    :param use_rms_prop: RMSprop (A2C's original optimiser) rather than Adam
    :param per_agent_updates: one optimiser step per AV slot on that slot's ``n_steps`` transitions
        (the authors' cadence: as many steps per rollout as slots; each later step's loss is the
        unclipped importance-weighted policy gradient, its ratio stays close to 1) instead of
        one step on the whole rollout (SB3's A2C)

    Other parameters: as SB3's ``A2C``.
    """

    def __init__(
        self,
        policy: Any,
        env: GymEnv | str | None,
        learning_rate: float | Schedule = 7e-4,
        n_steps: int = 5,
        gamma: float = 0.99,
        gae_lambda: float = 1.0,
        ent_coef: float = 0.0,
        vf_coef: float = 0.5,
        max_grad_norm: float = 0.5,
        rms_prop_eps: float = 1e-5,
        use_rms_prop: bool = True,
        normalize_advantage: bool = False,
        action_masking: bool = True,
        per_agent_updates: bool = False,
        rollout_buffer_class: type[RolloutBuffer] | None = None,
        rollout_buffer_kwargs: dict[str, Any] | None = None,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        _init_setup_model: bool = True,
    ) -> None:
        policy_kwargs = dict(policy_kwargs or {})
        if use_rms_prop and "optimizer_class" not in policy_kwargs:
            policy_kwargs["optimizer_class"] = th.optim.RMSprop
            policy_kwargs["optimizer_kwargs"] = dict(alpha=0.99, eps=rms_prop_eps, weight_decay=0)
        self.per_agent_updates = bool(per_agent_updates)
        if self.per_agent_updates and rollout_buffer_class is None:
            rollout_buffer_class = PerAgentRolloutBuffer
        super().__init__(
            policy,
            env,
            learning_rate=learning_rate,
            n_steps=n_steps,
            batch_size=None,  # the whole rollout in one batch
            n_epochs=1,  # one gradient step per rollout
            gamma=gamma,
            gae_lambda=gae_lambda,
            clip_range=math.inf,  # no clipping: the ratio is 1 at the only step anyway
            normalize_advantage=normalize_advantage,
            ent_coef=ent_coef,
            vf_coef=vf_coef,
            max_grad_norm=max_grad_norm,
            rollout_buffer_class=rollout_buffer_class,
            rollout_buffer_kwargs=rollout_buffer_kwargs,
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            policy_kwargs=policy_kwargs,
            verbose=verbose,
            seed=seed,
            device=device,
            _init_setup_model=_init_setup_model,
            action_masking=action_masking,
        )

    def learn(self, total_timesteps: int, callback: Any = None, log_interval: int = 10, tb_log_name: str = "MA2C",
              reset_num_timesteps: bool = True, use_masking: bool = True, progress_bar: bool = False) -> MaskableA2C:
        """sb3-contrib's ``learn``; the logger is dumped every ``log_interval`` updates (10: A2C's
        updates are many and small; MaskablePPO's default of 1 floods the console)."""
        return super().learn(total_timesteps, callback, log_interval, tb_log_name, reset_num_timesteps, use_masking,
                             progress_bar)

    def train(self) -> None:
        """One A2C update; also logs the advantages' mean and std (learning diagnostics)."""
        advantages = self.rollout_buffer.advantages
        self.logger.record("train/advantage_mean", float(advantages.mean()))
        self.logger.record("train/advantage_std", float(advantages.std()))
        super().train()


def uses_action_masks(model: BaseAlgorithm) -> bool:
    """Whether ``model`` acts on action masks (a maskable learner with ``action_masking`` on)."""
    return bool(getattr(model, "action_masking", False))
