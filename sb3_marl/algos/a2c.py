"""MA2C: A2C (SB3's arguments, defaults and loss) with action masks, the authors' per-slot update
cadence or one step per rollout at the learning rate x slots, and the project's rollout
(:class:`~sb3_marl.algos.common.base.MaskableOnPolicy`); its update (:meth:`MaskableA2C.train`)
reads top to bottom here. The class builds on sb3-contrib's ``MaskablePPO`` only for its masked
policy and rollout buffer set-up, ``predict`` and saving."""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Iterator
from typing import Any, ClassVar

import numpy as np
import torch as th
import torch.nn.functional as F
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, Schedule
from stable_baselines3.common.utils import explained_variance, update_learning_rate

from sb3_marl.algos.common.base import ACTOR_CRITIC_POLICIES
from sb3_marl.algos.common.buffers import PerAgentDictRolloutBuffer, PerAgentRolloutBuffer
from sb3_marl.algos.common.policies import clip_gradients
from sb3_marl.algos.ppo import MaskableActorCritic
from sb3_marl.common.checks import invalid


def check_cadence(per_agent_updates: Any, scale_lr_by_slots: Any) -> None:
    """Both flags booleans, ``scale_lr_by_slots`` only without ``per_agent_updates``: a ValueError
    naming the flag (a command line's bare ``false`` is the string "false", which would be true)."""
    for key, value in (("per_agent_updates", per_agent_updates), ("scale_lr_by_slots", scale_lr_by_slots)):
        if not isinstance(value, bool):
            raise invalid(key, value, "true or false (True or False in a key:value on the command line)")
    if scale_lr_by_slots and per_agent_updates:
        raise ValueError(
            "scale_lr_by_slots: true needs per_agent_updates: false (the per-slot cadence takes "
            "one step of the learning rate per slot already)."
        )


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
        (the authors' cadence: as many A2C steps per rollout as slots, in a random order) instead
        of one step on the whole rollout (SB3's A2C)
    :param importance_weights: weight each sample's policy gradient by ``pi(a|s) / pi_rollout(a|s)``,
        the policy at the step over the one that sampled the rollout: 1 at a rollout's first step,
        the off-policy correction of the later per-slot steps (each sees a policy the earlier slots'
        steps moved). False: the plain A2C loss at every step (the authors' code, with one road and
        4-6 slots; with 15 slots at density 3 it learned worse: ``results/a2c-update/``)
    :param scale_lr_by_slots: without ``per_agent_updates``, the one step on the whole rollout
        takes the learning rate times the number of AV slots, the step per AV-sample of the
        per-slot cadence (whose rollout takes one step of the learning rate per slot)

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
        importance_weights: bool = True,
        scale_lr_by_slots: bool = False,
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
        self.per_agent_updates = per_agent_updates
        self.importance_weights = bool(importance_weights)
        self.scale_lr_by_slots = scale_lr_by_slots
        super().__init__(
            policy,
            env,
            learning_rate=learning_rate,
            n_steps=n_steps,
            batch_size=None,  # MaskablePPO's arguments, unused by A2C's update (train)
            n_epochs=1,
            gamma=gamma,
            gae_lambda=gae_lambda,
            clip_range=math.inf,
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
    known_classes: ClassVar[tuple[type, ...]] = (PerAgentRolloutBuffer, PerAgentDictRolloutBuffer)  # older zips

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

    def _setup_model(self) -> None:
        """SB3's, after checking the update cadence (``load`` sets the saved and the given attributes
        before it calls this)."""
        check_cadence(self.per_agent_updates, self.scale_lr_by_slots)
        super()._setup_model()

    def _minibatches(self) -> Iterator[np.ndarray]:
        """Indices of the flattened (slot-major) rollout buffer: one array per AV slot in a random
        order (numpy's global generator) with ``per_agent_updates``, else the whole rollout (in
        the order of one permutation, as MAPPO's minibatches)."""
        if not self.per_agent_updates:
            yield from super()._minibatches()
            return
        buffer = self.rollout_buffer
        steps, n_envs = buffer.buffer_size, buffer.n_envs
        if not buffer.generator_ready:  # sb3-contrib flattens the arrays slot-major on first use
            next(buffer.get(None))
        for slot in np.random.permutation(n_envs):
            yield np.arange(slot * steps, (slot + 1) * steps)

    def train(self) -> None:
        """One A2C update (SB3's ``A2C.train``, with the action masks): for each minibatch of
        :meth:`_minibatches` the loss ``-A w + vf_coef (R - V(s))^2 - ent_coef H(pi(.|s))`` with
        ``w = pi(a|s) / pi_rollout(a|s)`` (``importance_weights``; its gradient ``-A w grad log pi``
        is A2C's policy gradient, importance-weighted; ``w`` is 1 at a rollout's first step), or
        ``-A log pi(a|s)`` without the weights, plus the rule prior's term (:meth:`prior_term`),
        and one optimiser step with the gradients' norm clipped at ``max_grad_norm``; then the
        supervisor teacher's step."""
        self.policy.set_training_mode(True)
        self._update_learning_rate(self.policy.optimizer)
        learning_rate = self.lr_schedule(self._current_progress_remaining)
        if self.scale_lr_by_slots:
            update_learning_rate(self.policy.optimizer, learning_rate * self.n_envs)
            self.logger.record("train/learning_rate", learning_rate * self.n_envs)
        logs: dict[str, list] = defaultdict(list)
        for indices in self._minibatches():
            data = self.rollout_buffer._get_samples(indices)
            values, log_prob, entropy = self.policy.evaluate_actions(
                data.observations, data.actions.long().flatten(), action_masks=data.action_masks
            )
            advantages = data.advantages
            if self.normalize_advantage:
                advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
            if self.importance_weights:
                policy_loss = -(advantages * th.exp(log_prob - data.old_log_prob)).mean()
            else:
                policy_loss = -(advantages * log_prob).mean()
            value_loss = F.mse_loss(data.returns, values.flatten())
            entropy_loss = -th.mean(-log_prob) if entropy is None else -th.mean(entropy)
            loss = policy_loss + self.ent_coef * entropy_loss + self.vf_coef * value_loss
            loss = loss + self.prior_term(data.observations, data.action_masks, indices, logs)
            self.policy.optimizer.zero_grad()
            loss.backward()
            clip_gradients(self.policy.optimizer, self.max_grad_norm)
            self.policy.optimizer.step()
            logs["policy_loss"].append(policy_loss.item())
            logs["value_loss"].append(value_loss.item())
            logs["entropy_loss"].append(entropy_loss.item())
        self._n_updates += 1
        update_learning_rate(self.policy.optimizer, learning_rate)  # the teacher's step takes it unscaled
        buffer = self.rollout_buffer
        for key, entries in logs.items():
            self.logger.record(f"train/{key}", float(np.mean(entries)))
        self.logger.record("train/explained_variance", explained_variance(buffer.values.flatten(), buffer.returns.flatten()))
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        self.logger.record("train/advantage_mean", float(buffer.advantages.mean()))
        self.logger.record("train/advantage_std", float(buffer.advantages.std()))
        executed = self.rollout_extras.executed
        if self.safety_loss_coef > 0 and executed is not None:  # the teacher's step
            self.safety_step(executed)
