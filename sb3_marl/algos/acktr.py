"""ACKTR: actor-critic using a Kronecker-factored trust region, as a Stable-Baselines3 algorithm.

Wu, Mansimov, Liao, Grosse and Ba (2017), "Scalable trust-region method for deep reinforcement
learning using Kronecker-factored approximation". ACKTR is A2C (synchronous n-step rollouts, one
update per rollout) whose optimiser is K-FAC (Martens and Grosse 2015; Grosse and Martens 2016
for convolutions): natural-gradient steps under a Kronecker-factored Fisher, scaled down to a
trust region on the KL divergence between successive policies.

The optimiser is :class:`~sb3_marl.algos.common.kfac.KFAC` (curvature statistics, preconditioning, trust
region, update); :class:`ACKTR` is the SB3 algorithm (rollouts as A2C, ``train`` feeds K-FAC its
statistics), :class:`MaskableACKTR` the learner ``maacktr`` on the maskable machinery.

Choices, after OpenAI baselines' ``acktr`` and ikostrikov's pytorch-a2c-ppo-acktr-gail:

- learning rate 0.25, momentum 0.9, KL clip 0.001, damping 0.01 (baselines' and ikostrikov's);
- running averages of the factors with decay 0.99, updated on every update (``stats_update_freq``
  1, ikostrikov's ``Ts``); eigen-decompositions every 10 updates (``inverse_update_freq``,
  ikostrikov's ``Tf``), synchronously (baselines runs them asynchronously on a queue);
- the Fisher of the policy from actions sampled from the policy itself: the rollout's actions, as
  one update per rollout means they were drawn from the current parameters; the Fisher of the
  critic from a Gaussian value head with unit variance (targets ``value + N(0, 1)``);
- no gradient-norm clipping: the KL clip bounds the step.
"""

from __future__ import annotations

import math
from collections import defaultdict
from contextlib import nullcontext
from typing import Any, ClassVar, TypeVar

import numpy as np
import torch as th
import torch.nn.functional as F
from gymnasium import spaces
from sb3_contrib.common.maskable.buffers import MaskableDictRolloutBuffer, MaskableRolloutBuffer
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
from stable_baselines3.common.policies import (
    ActorCriticCnnPolicy,
    ActorCriticPolicy,
    BasePolicy,
    MultiInputActorCriticPolicy,
)
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule
from stable_baselines3.common.utils import explained_variance

from sb3_marl.algos.common.base import ACTOR_CRITIC_POLICIES, MaskableOnPolicy
from sb3_marl.algos.common.kfac import KFAC

SelfACKTR = TypeVar("SelfACKTR", bound="ACKTR")


class ACKTR(OnPolicyAlgorithm):
    """ACKTR: A2C-style actor-critic trained with :class:`KFAC` (see the module doc).

    Same policies as SB3's A2C (``MlpPolicy``, ``CnnPolicy``, ``MultiInputPolicy``, and the MA2C
    feature extractor through ``policy_kwargs``); Discrete, MultiDiscrete, MultiBinary and Box
    action spaces; saved and loaded in SB3's format (K-FAC's statistics included).

    :param learning_rate: K-FAC learning rate, or a schedule of the remaining progress
    :param n_steps: steps per env per update (rollout length)
    :param gamma: discount factor
    :param gae_lambda: GAE lambda; 1.0 gives plain n-step returns, as in the paper
    :param ent_coef: entropy coefficient
    :param vf_coef: value loss coefficient
    :param momentum: K-FAC SGD momentum
    :param stat_decay: decay of K-FAC's running curvature averages
    :param damping: K-FAC damping
    :param kl_clip: trust-region bound on the KL estimate of one update
    :param inverse_update_freq: updates between eigen-decompositions of the factors
    :param stats_update_freq: updates between curvature-statistics recordings
    :param vf_fisher_coef: weight of the critic's Gaussian Fisher loss beside the policy's
    :param normalize_advantage: whether to normalise the advantages of each rollout
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {
        "MlpPolicy": ActorCriticPolicy,
        "CnnPolicy": ActorCriticCnnPolicy,
        "MultiInputPolicy": MultiInputActorCriticPolicy,
    }

    def __init__(
        self,
        policy: str | type[ActorCriticPolicy],
        env: GymEnv | str,
        learning_rate: float | Schedule = 0.25,
        n_steps: int = 20,
        gamma: float = 0.99,
        gae_lambda: float = 1.0,
        ent_coef: float = 0.01,
        vf_coef: float = 0.5,
        momentum: float = 0.9,
        stat_decay: float = 0.99,
        damping: float = 1e-2,
        kl_clip: float = 1e-3,
        inverse_update_freq: int = 10,
        stats_update_freq: int = 1,
        vf_fisher_coef: float = 1.0,
        normalize_advantage: bool = False,
        use_sde: bool = False,
        sde_sample_freq: int = -1,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        _init_setup_model: bool = True,
    ) -> None:
        super().__init__(
            policy,
            env,
            learning_rate=learning_rate,
            n_steps=n_steps,
            gamma=gamma,
            gae_lambda=gae_lambda,
            ent_coef=ent_coef,
            vf_coef=vf_coef,
            max_grad_norm=math.inf,  # unused: the KL clip bounds the step
            use_sde=use_sde,
            sde_sample_freq=sde_sample_freq,
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            policy_kwargs=policy_kwargs,
            verbose=verbose,
            seed=seed,
            device=device,
            _init_setup_model=False,
            supported_action_spaces=(spaces.Box, spaces.Discrete, spaces.MultiDiscrete, spaces.MultiBinary),
        )
        if not isinstance(stats_update_freq, int) or stats_update_freq < 1:
            raise ValueError(f"Invalid stats_update_freq={stats_update_freq!r}: expected an integer >= 1.")
        self.momentum = momentum
        self.stat_decay = stat_decay
        self.damping = damping
        self.kl_clip = kl_clip
        self.inverse_update_freq = inverse_update_freq
        self.stats_update_freq = stats_update_freq
        self.vf_fisher_coef = vf_fisher_coef
        self.normalize_advantage = normalize_advantage
        if _init_setup_model:
            self._setup_model()

    def _setup_model(self) -> None:
        super()._setup_model()
        self._setup_optimizer()

    def _setup_optimizer(self) -> None:
        """Replace the policy's optimiser with :class:`KFAC` (hooks on its layers)."""
        self.policy.optimizer = KFAC(
            self.policy,
            lr=self.lr_schedule(1),
            momentum=self.momentum,
            stat_decay=self.stat_decay,
            damping=self.damping,
            kl_clip=self.kl_clip,
            inverse_update_freq=self.inverse_update_freq,
        )

    def train(self) -> None:
        """One K-FAC update on the rollout buffer (one batch)."""
        self.policy.set_training_mode(True)
        optimizer: KFAC = self.policy.optimizer  # type: ignore[assignment]
        self._update_learning_rate(optimizer)
        buffer = self.rollout_buffer
        indices = np.random.permutation(buffer.buffer_size * buffer.n_envs)  # as the buffer's get() draws it
        if not buffer.generator_ready:
            state = np.random.get_state()
            next(buffer.get(batch_size=None))  # flattens the arrays slot-major on first use
            np.random.set_state(state)
        rollout = buffer._get_samples(indices)
        actions = rollout.actions
        if isinstance(self.action_space, spaces.Discrete):
            actions = actions.long().flatten()

        record = self._n_updates % self.stats_update_freq == 0
        with optimizer.record_statistics() if record else nullcontext():
            masks = getattr(rollout, "action_masks", None)  # a maskable rollout buffer's (MaskableACKTR)
            mask_kwargs = {} if masks is None else {"action_masks": masks}
            values, log_prob, entropy = self.policy.evaluate_actions(rollout.observations, actions, **mask_kwargs)
            values = values.flatten()
            if record:  # Fisher loss: log-likelihood of model samples (see the module doc)
                optimizer.zero_grad()
                value_samples = values.detach() + th.randn_like(values)
                fisher_loss = -log_prob.mean() - self.vf_fisher_coef * (values - value_samples).pow(2).mean()
                fisher_loss.backward(retain_graph=True)

        advantages = rollout.advantages
        if self.normalize_advantage:
            advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
        policy_loss = -(advantages * log_prob).mean()
        value_loss = F.mse_loss(rollout.returns, values)
        entropy_loss = -th.mean(-log_prob) if entropy is None else -th.mean(entropy)
        loss = policy_loss + self.ent_coef * entropy_loss + self.vf_coef * value_loss
        loss = loss + self.auxiliary_loss(rollout, indices)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()

        self._n_updates += 1
        explained_var = explained_variance(self.rollout_buffer.values.flatten(), self.rollout_buffer.returns.flatten())
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        self.logger.record("train/explained_variance", explained_var)
        self.logger.record("train/entropy_loss", entropy_loss.item())
        self.logger.record("train/policy_loss", policy_loss.item())
        self.logger.record("train/value_loss", value_loss.item())
        self.logger.record("train/kl_step_scale", optimizer.last_step_scale)
        if hasattr(self.policy, "log_std"):
            self.logger.record("train/std", th.exp(self.policy.log_std).mean().item())

    def auxiliary_loss(self, rollout: Any, indices: np.ndarray) -> th.Tensor | float:
        """A term added to the update's loss on ``rollout`` (the buffer's samples at ``indices``):
        none here; subclasses add theirs in the same K-FAC step."""
        return 0.0

    def learn(
        self: SelfACKTR,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 100,
        tb_log_name: str = "ACKTR",
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfACKTR:
        return super().learn(
            total_timesteps=total_timesteps,
            callback=callback,
            log_interval=log_interval,
            tb_log_name=tb_log_name,
            reset_num_timesteps=reset_num_timesteps,
            progress_bar=progress_bar,
        )


class MaskableACKTR(MaskableOnPolicy, ACKTR):
    """Our :class:`~sb3_marl.algos.acktr.ACKTR` on sb3-contrib's maskable policy, rollout buffer and
    masked rollouts (see the module doc); ACKTR's update evaluates the actions under their masks,
    and its loss takes the rule prior's term (:meth:`auxiliary_loss`)."""

    def auxiliary_loss(self, rollout: Any, indices: np.ndarray) -> Any:
        logs: dict[str, list] = defaultdict(list)
        term = self.prior_term(rollout.observations, rollout.action_masks, indices, logs)
        for key, values in logs.items():
            self.logger.record(f"train/{key}", float(np.mean(values)))
        return term

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = ACTOR_CRITIC_POLICIES
    left_out: ClassVar[tuple[str, ...]] = ("safety_loss_coef",)  # K-FAC's step has no teacher's step after it

    def _setup_model(self) -> None:
        """As ``MaskablePPO._setup_model`` (maskable policy and rollout buffer), then K-FAC."""
        self._setup_lr_schedule()
        self.set_random_seed(self.seed)
        self.policy = self.policy_class(self.observation_space, self.action_space, self.lr_schedule, **self.policy_kwargs).to(  # type: ignore[assignment]
            self.device
        )
        buffer_class = MaskableDictRolloutBuffer if isinstance(self.observation_space, spaces.Dict) else MaskableRolloutBuffer
        self.rollout_buffer = buffer_class(
            self.n_steps,
            self.observation_space,  # type: ignore[arg-type]
            self.action_space,
            self.device,
            gamma=self.gamma,
            gae_lambda=self.gae_lambda,
            n_envs=self.n_envs,
        )
        self._setup_optimizer()
