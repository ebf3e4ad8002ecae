"""MA2C: A2C (SB3's arguments and defaults) on the maskable actor-critic update, as the authors'
MA2C (see :class:`MaskableA2C`)."""

from __future__ import annotations

import math
from typing import Any, ClassVar

import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, Schedule

from sb3_marl.algos.common.base import ACTOR_CRITIC_POLICIES
from sb3_marl.algos.common.buffers import PerAgentDictRolloutBuffer, PerAgentRolloutBuffer
from sb3_marl.algos.ppo import MaskableActorCritic


class MaskableA2C(MaskableActorCritic):
    """A2C (SB3's arguments and defaults) with invalid-action masking (see the module doc).

    :param action_masking: sample only available meta-actions (the authors' MA2C) or all of them
    :param rms_prop_eps: RMSprop epsilon (with ``use_rms_prop``; RMSprop alpha 0.99 as SB3's A2C)
    :param use_rms_prop: RMSprop (A2C's original optimiser) rather than Adam
    :param safety_loss_coef: weight of the safety supervisor's teaching loss
        (:func:`~sb3_marl.algos.common.teacher.safety_step`; 0: off)
    :param prior: ``idm-mobil``: start from the rule driver and regularise toward it
        (:mod:`sb3_marl.algos.common.rule_prior`, with ``prior_warm_start``, ``prior_coef``,
        ``prior_coef_final``, ``prior_decay_steps``, ``prior_smoothing``, ``prior_form``); None: off
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
        safety_loss_coef: float = 0.0,
        per_agent_updates: bool = False,
        prior: str | None = None,
        prior_warm_start: int = 0,
        prior_coef: float = 1.0,
        prior_coef_final: float = 0.0,
        prior_decay_steps: int = 1,
        prior_smoothing: float = 0.0,
        prior_form: str = "cross-entropy",
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
            safety_loss_coef=safety_loss_coef,
            prior=prior,
            prior_warm_start=prior_warm_start,
            prior_coef=prior_coef,
            prior_coef_final=prior_coef_final,
            prior_decay_steps=prior_decay_steps,
            prior_smoothing=prior_smoothing,
            prior_form=prior_form,
        )

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = ACTOR_CRITIC_POLICIES
    known_classes: ClassVar[tuple[type, ...]] = (PerAgentRolloutBuffer, PerAgentDictRolloutBuffer)

    def _setup_model(self) -> None:
        if self.per_agent_updates and self.rollout_buffer_class is None:
            dict_obs = isinstance(self.observation_space, spaces.Dict)
            self.rollout_buffer_class = PerAgentDictRolloutBuffer if dict_obs else PerAgentRolloutBuffer
        super()._setup_model()

    def learn(  # type: ignore[override]
        self,
        total_timesteps: int,
        callback: Any = None,
        log_interval: int = 10,
        tb_log_name: str = "MA2C",
        reset_num_timesteps: bool = True,
        use_masking: bool = True,
        progress_bar: bool = False,
    ) -> MaskableA2C:
        """sb3-contrib's ``learn``; the logger is dumped every ``log_interval`` updates (10: A2C's
        updates are many and small; MaskablePPO's default of 1 floods the console)."""
        return super().learn(
            total_timesteps, callback, log_interval, tb_log_name, reset_num_timesteps, use_masking, progress_bar
        )

    def train(self) -> None:
        """One A2C update; also logs the advantages' mean and std (learning diagnostics)."""
        advantages = self.rollout_buffer.advantages
        self.logger.record("train/advantage_mean", float(advantages.mean()))
        self.logger.record("train/advantage_std", float(advantages.std()))
        super().train()
