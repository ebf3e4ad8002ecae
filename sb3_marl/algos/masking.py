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

Both take ``action_masking`` (default True): False trains and acts without masks (the unmasked
learner of the ablation) with the same network. The setting is saved with the model, and
``predict(obs, action_masks=...)`` takes masks exactly as sb3-contrib's maskable algorithms do.
"""

from __future__ import annotations

import math
from typing import Any, TypeVar

import numpy as np
import torch as th
from sb3_contrib import MaskablePPO
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.type_aliases import GymEnv, Schedule

SelfMasking = TypeVar("SelfMasking", bound="ActionMaskingMixin")


class ActionMaskingMixin:
    """``action_masking`` switch of a maskable learner: masks in training (``learn``) and acting
    (``predict``) only when it is True."""

    action_masking: bool = True

    def learn(self: SelfMasking, *args: Any, use_masking: bool | None = None, **kwargs: Any) -> SelfMasking:
        """sb3-contrib's ``learn``; ``use_masking`` defaults to the model's ``action_masking``."""
        return super().learn(*args, use_masking=self.action_masking if use_masking is None else use_masking, **kwargs)

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
        return super().predict(observation, state, episode_start, deterministic, action_masks=masks)


class MaskedPPO(ActionMaskingMixin, MaskablePPO):
    """sb3-contrib's ``MaskablePPO`` with the ``action_masking`` switch (see the module doc)."""

    def __init__(self, policy: Any, env: GymEnv | str | None, *args: Any, action_masking: bool = True, **kwargs: Any):
        self.action_masking = bool(action_masking)
        super().__init__(policy, env, *args, **kwargs)


class MaskableA2C(ActionMaskingMixin, MaskablePPO):
    """A2C (SB3's arguments and defaults) with invalid-action masking (see the module doc).

    :param action_masking: sample only available meta-actions (the authors' MA2C) or all of them
    :param rms_prop_eps: RMSprop epsilon (with ``use_rms_prop``; RMSprop alpha 0.99 as SB3's A2C)
    :param use_rms_prop: RMSprop (A2C's original optimiser) rather than Adam

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
        self.action_masking = bool(action_masking)
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
        )


    def train(self) -> None:
        """One A2C update; also logs the advantages' mean and std (learning diagnostics)."""
        advantages = self.rollout_buffer.advantages
        self.logger.record("train/advantage_mean", float(advantages.mean()))
        self.logger.record("train/advantage_std", float(advantages.std()))
        super().train()


def uses_action_masks(model: BaseAlgorithm) -> bool:
    """Whether ``model`` acts on action masks (a maskable learner with ``action_masking`` on)."""
    return bool(getattr(model, "action_masking", False))
