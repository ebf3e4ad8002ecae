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
from collections import defaultdict
from collections.abc import Iterator
from typing import Any, ClassVar, NamedTuple

import numpy as np
import torch as th
import torch.nn.functional as F
from gymnasium import spaces
from sb3_contrib import TRPO, MaskablePPO
from sb3_contrib.common.maskable.buffers import MaskableDictRolloutBuffer, MaskableRolloutBuffer
from sb3_contrib.common.maskable.utils import get_action_masks
from stable_baselines3 import DQN
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.buffers import ReplayBuffer, RolloutBuffer
from stable_baselines3.common.callbacks import BaseCallback, CallbackList
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, Schedule
from stable_baselines3.common.utils import explained_variance

from sb3_marl.algos.acktr import ACKTR
from sb3_marl.algos.rule_prior import RuleLabels, RulePrior, dagger, masked_logits, prior_loss
from sb3_marl.loading import SafeLoading
from sb3_marl.policies import CentralisedCriticPolicy

#: Policies of the maskable actor-critic learners: sb3-contrib's, plus the centralised critic
#: (``critic: centralised``, selected by the hyperparameters under this alias).
ACTOR_CRITIC_POLICIES: dict[str, type[BasePolicy]] = {
    **MaskablePPO.policy_aliases,
    CentralisedCriticPolicy.__name__: CentralisedCriticPolicy,
}


class MaskingLearner(SafeLoading):
    """What every learner of this module takes and saves: the ``action_masking`` switch, the
    ``safety_loss_coef`` of learning from the safety supervisor (see :class:`SupervisorTeacher`),
    and its class name (``algorithm_class`` in the zip's data, so that loading a model as another
    algorithm is refused by name: :func:`sb3_marl.runs.check_model_file`). Loading a model
    restores the saved values over these, and never unpickles (:class:`~sb3_marl.loading.SafeLoading`)."""

    def __init__(self, *args: Any, action_masking: bool = True, safety_loss_coef: float = 0.0, **kwargs: Any) -> None:
        self.algorithm_class = type(self).__name__
        self.action_masking = bool(action_masking)
        self.safety_loss_coef = check_safety_loss_coef(safety_loss_coef)
        super().__init__(*args, **kwargs)


def check_safety_loss_coef(coef: Any) -> float:
    """``safety_loss_coef`` as a float; a ValueError naming it unless a finite number >= 0."""
    if isinstance(coef, bool) or not isinstance(coef, (int, float)) or not 0 <= coef < math.inf:
        raise ValueError(f"Invalid safety_loss_coef={coef!r}: expected a finite number >= 0 (0: off).")
    return float(coef)


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


class SupervisorTeacher:
    """The safety supervisor as a teacher of an on-policy maskable learner (``safety_loss_coef`` > 0).

    After each update, one more optimiser step on the auxiliary loss
    ``safety_loss_coef * mean(-log π(executed | s))`` over the rollout's steps where the supervisor
    replaced the policy's proposal (the action it executed is the label): the policy learns to
    propose what the supervisor would have done, so that it stays safe without it. Steps without
    an intervention contribute nothing; a rollout without any leaves the policy unchanged.
    Logged as ``train/safety_loss`` and ``train/intervened_share``.
    """

    safety_loss_coef: float = 0.0
    _recorder: InterventionRecorder | None = None

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "_recorder"]  # type: ignore[misc]

    def with_recorder(self, callback: Any, n_rollout_steps: int, n_envs: int) -> Any:
        """``callback`` plus the intervention recorder when the teacher is on."""
        if self.safety_loss_coef <= 0:
            return callback
        if self._recorder is None or self._recorder.executed.shape != (n_rollout_steps, n_envs):
            self._recorder = InterventionRecorder(n_rollout_steps, n_envs)
            self._recorder.init_callback(self)  # type: ignore[arg-type]
        together = _InitialisedCallbacks([callback, self._recorder])
        together.init_callback(self)  # type: ignore[arg-type]
        return together

    def safety_loss(self, observations: th.Tensor, action_masks: np.ndarray | None, executed: th.Tensor) -> th.Tensor:
        """``-log π(executed | s)`` averaged over the given (intervened) samples."""
        distribution = self.policy.get_distribution(observations, action_masks=action_masks)  # type: ignore[attr-defined]
        return -distribution.log_prob(executed).mean()

    def safety_step(self, executed: np.ndarray) -> float:
        """One optimiser step on the auxiliary loss over the rollout buffer's samples whose entry
        of ``executed`` ((n_steps, n_envs), -1: no intervention) names the supervisor's action;
        returns the loss before the step (0 without intervened samples)."""
        buffer = self.rollout_buffer  # type: ignore[attr-defined]
        labels = executed.swapaxes(0, 1).reshape(-1) if buffer.generator_ready else executed.reshape(-1)
        observations = _flat_samples(buffer.observations, buffer.obs_shape, len(labels))
        masks = buffer.action_masks.reshape(len(labels), -1) if self.action_masking else None  # type: ignore[attr-defined]
        chosen = np.flatnonzero(labels >= 0)
        self.logger.record("train/intervened_share", chosen.size / max(len(labels), 1))  # type: ignore[attr-defined]
        if chosen.size == 0:
            self.logger.record("train/safety_loss", 0.0)  # type: ignore[attr-defined]
            return 0.0
        policy = self.policy  # type: ignore[attr-defined]
        policy.set_training_mode(True)
        loss = self.safety_loss(
            policy.obs_to_tensor(_select(observations, chosen))[0],
            None if masks is None else masks[chosen],
            th.as_tensor(labels[chosen], device=policy.device),
        )
        policy.optimizer.zero_grad()
        (self.safety_loss_coef * loss).backward()
        th.nn.utils.clip_grad_norm_(policy.parameters(), self.max_grad_norm)  # type: ignore[attr-defined]
        policy.optimizer.step()
        self.logger.record("train/safety_loss", float(loss.item()))  # type: ignore[attr-defined]
        return float(loss.item())


def _flat_samples(observations: Any, obs_shape: Any, n: int) -> Any:
    """A rollout buffer's observations (an array, or a dict of arrays) as ``n`` samples."""
    if isinstance(observations, dict):
        return {key: value.reshape(n, *obs_shape[key]) for key, value in observations.items()}
    return observations.reshape(n, *obs_shape)


def _select(observations: Any, rows: np.ndarray) -> Any:
    if isinstance(observations, dict):
        return {key: value[rows] for key, value in observations.items()}
    return observations[rows]


class RulePriorLearner:
    """The rule prior of an on-policy actor-critic (``prior``, ``prior_warm_start``, ``prior_coef``,
    ``prior_coef_final``, ``prior_decay_steps``, ``prior_smoothing``; :mod:`sb3_marl.algos.rule_prior`):
    the DAgger warm start when learning starts, the rule driver's labels of each rollout, and the
    prior's term of the loss. The values are saved with the model (plain attributes)."""

    prior: str | None = None
    prior_warm_start: int = 0
    prior_coef: float = 1.0
    prior_coef_final: float = 0.0
    prior_decay_steps: int = 1
    prior_smoothing: float = 0.0
    _rule_labels: np.ndarray | None = None

    def __init__(
        self,
        *args: Any,
        prior: str | None = None,
        prior_warm_start: int = 0,
        prior_coef: float = 1.0,
        prior_coef_final: float = 0.0,
        prior_decay_steps: int = 1,
        prior_smoothing: float = 0.0,
        **kwargs: Any,
    ) -> None:
        settings = RulePrior(prior, prior_warm_start, prior_coef, prior_coef_final, prior_decay_steps, prior_smoothing)
        self.__dict__.update(settings.as_kwargs())
        super().__init__(*args, **kwargs)

    @property
    def rule_prior(self) -> RulePrior:
        return RulePrior.from_kwargs({key: getattr(self, key) for key in RulePrior().as_kwargs()})

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "_rule_labels"]  # type: ignore[misc]

    def _setup_learn(self, *args: Any, **kwargs: Any) -> Any:
        """SB3's set-up, then the DAgger warm start where the budget's first ``prior_warm_start``
        AV-steps are still ahead."""
        result = super()._setup_learn(*args, **kwargs)  # type: ignore[misc]
        prior = self.rule_prior
        if prior.active and self.num_timesteps < prior.warm_start:  # type: ignore[attr-defined]
            dagger(self, prior.warm_start - self.num_timesteps, prior)  # type: ignore[attr-defined]
        return result

    def labelled(self, env: Any, n_rollout_steps: int) -> Any:
        """``env`` recording the rule driver's labels of the rollout (when the prior's weight is on)."""
        if self.rule_prior.weight(self.num_timesteps) <= 0:  # type: ignore[attr-defined]
            self._rule_labels = None
            return env
        labelled = RuleLabels(env, n_rollout_steps)
        self._rule_labels = labelled.labels
        return labelled

    def prior_term(self, observations: Any, action_masks: Any, indices: np.ndarray, logs: dict[str, list]) -> Any:
        """``w · prior_loss`` of the rollout's samples at ``indices`` (of the flattened, slot-major
        buffer), 0 without labels; logs the loss, its KL and the weight."""
        weight = self.rule_prior.weight(self.num_timesteps)  # type: ignore[attr-defined]
        if self._rule_labels is None or weight <= 0:
            return 0.0
        policy: Any = self.policy  # type: ignore[attr-defined]
        labels = th.as_tensor(self._rule_labels.swapaxes(0, 1).reshape(-1)[indices], device=policy.device)
        loss, kl = prior_loss(masked_logits(policy, observations, action_masks), labels, self.prior_smoothing, action_masks)
        logs["prior_loss"].append(loss.item())
        logs["prior_kl"].append(kl.item())
        logs["prior_coef"].append(weight)
        return weight * loss


class ActionMaskingMixin(RulePriorLearner, SupervisorTeacher, MaskingLearner):
    """``action_masking`` switch of a maskable on-policy learner: sb3-contrib's masked rollouts
    and ``predict(..., action_masks=...)``, with masks only when ``action_masking`` is True; the
    supervisor as a teacher (:class:`SupervisorTeacher`) and the rule prior (:class:`RulePriorLearner`)."""

    action_masking: bool = True

    def collect_rollouts(
        self, env: Any, callback: Any, rollout_buffer: Any, n_rollout_steps: int, use_masking: bool = True
    ) -> bool:
        """sb3-contrib's masked rollout collection (``MaskablePPO.collect_rollouts``), recording the
        supervisor's interventions for the teacher's loss and the rule driver's labels for the prior's."""
        callback = self.with_recorder(callback, n_rollout_steps, env.num_envs)
        return MaskablePPO.collect_rollouts(
            self,  # type: ignore[arg-type]
            self.labelled(env, n_rollout_steps),
            callback,
            rollout_buffer,
            n_rollout_steps,
            use_masking=use_masking and self.action_masking,
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
        return self.policy.predict(observation, state, episode_start, deterministic, action_masks=masks)  # type: ignore[attr-defined]


def _with_action_masking(cls: type, base: type, teacher: bool = True, prior: bool = True) -> None:
    """Give ``cls`` the constructor signature of ``base`` plus ``action_masking`` (and, with
    ``teacher``, ``safety_loss_coef``; with ``prior``, the rule prior's keys), so that the zoo
    configs' validation (which reads constructor signatures) sees every argument."""
    signature = inspect.signature(base)
    extra = [inspect.Parameter("action_masking", inspect.Parameter.KEYWORD_ONLY, default=True, annotation=bool)]
    if teacher:
        extra.append(inspect.Parameter("safety_loss_coef", inspect.Parameter.KEYWORD_ONLY, default=0.0, annotation=float))
    if prior:
        extra += [
            inspect.Parameter(key, inspect.Parameter.KEYWORD_ONLY, default=value)
            for key, value in RulePrior().as_kwargs().items()
        ]
    cls.__signature__ = signature.replace(parameters=[*signature.parameters.values(), *extra])  # type: ignore[attr-defined]


class MaskableActorCritic(ActionMaskingMixin, MaskablePPO):  # type: ignore[misc]
    """sb3-contrib's ``MaskablePPO`` with the ``action_masking`` switch (see the module doc), whose
    update adds the rule prior's term to each minibatch's loss (same loss, same optimiser step),
    then takes the supervisor teacher's step; minibatches are one per AV slot with
    ``per_agent_updates`` (:class:`MaskableA2C`)."""

    per_agent_updates: bool = False

    def _minibatches(self) -> Iterator[np.ndarray]:
        """Indices of the flattened (slot-major) rollout buffer, one array per minibatch, drawn from
        numpy's global generator in the same order as sb3-contrib's ``get`` (so seeded runs repeat
        those of the buffers' own generators)."""
        buffer = self.rollout_buffer
        steps, n_envs = buffer.buffer_size, buffer.n_envs
        flatten = (MaskableDictRolloutBuffer if isinstance(buffer, MaskableDictRolloutBuffer) else MaskableRolloutBuffer).get
        if self.per_agent_updates:
            if not buffer.generator_ready:
                next(flatten(buffer, None))  # sb3-contrib flattens the arrays slot-major on first use
            for slot in np.random.permutation(n_envs):
                yield np.arange(slot * steps, (slot + 1) * steps)
            return
        order = np.random.permutation(steps * n_envs)
        if not buffer.generator_ready:
            state = np.random.get_state()
            next(flatten(buffer, None))
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
                th.nn.utils.clip_grad_norm_(self.policy.parameters(), self.max_grad_norm)
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
        if self.safety_loss_coef > 0 and self._recorder is not None:
            self.safety_step(self._recorder.executed)


class MaskedPPO(MaskableActorCritic):
    """sb3-contrib's ``MaskablePPO`` with the ``action_masking`` switch (see the module doc)."""

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = ACTOR_CRITIC_POLICIES


class MaskableACKTR(ActionMaskingMixin, ACKTR):  # type: ignore[misc]
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


class MaskedReplayBufferSamples(NamedTuple):
    """SB3's ``ReplayBufferSamples`` plus the action mask of each next observation and the action
    the safety supervisor executed in place of the stored one (-1: it did not intervene)."""

    observations: th.Tensor
    actions: th.Tensor
    next_observations: th.Tensor
    dones: th.Tensor
    rewards: th.Tensor
    next_action_masks: th.Tensor
    executed_actions: th.Tensor
    discounts: th.Tensor | None = None


class MaskedReplayBuffer(ReplayBuffer):
    """SB3's ``ReplayBuffer`` that also keeps the action mask of every next observation, taken
    from the step infos' ``action_mask`` (the scenario reports the mask of the observation it
    returns; after an episode end, of the terminal observation; without one: all available), and
    the action the safety supervisor executed where it replaced the stored one (-1 elsewhere)."""

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

    def add(
        self,
        obs: np.ndarray,
        next_obs: np.ndarray,
        action: np.ndarray,
        reward: np.ndarray,
        done: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        self.next_action_masks[self.pos] = [info.get("action_mask", True) for info in infos]
        self.executed_actions[self.pos] = executed_labels(infos)
        super().add(obs, next_obs, action, reward, done, infos)

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
        )
        return MaskedReplayBufferSamples(*tuple(map(self.to_torch, data)))


class MaskableDQN(MaskingLearner, DQN):
    """SB3's DQN whose Q-values of unavailable meta-actions are excluded from the greedy action,
    from ε-greedy exploration (random actions among the available ones, also during warm-up) and
    from the bootstrap target ``max_a' Q_target(s', a')`` (over the actions available in s').

    With ``safety_loss_coef`` > 0 the safety supervisor is a teacher (as :class:`SupervisorTeacher`
    for the actor-critics): replayed transitions where it replaced the stored action add DQfD's
    large-margin loss ``safety_loss_coef * (max_a [Q(s, a) + margin·(a ≠ a_E)] - Q(s, a_E))``
    with a_E the executed action and margin :attr:`SAFETY_MARGIN`, so that the greedy action
    becomes the supervisor's.

    :param action_masking: use the env's action masks (True) or SB3's DQN unchanged (False)
    :param safety_loss_coef: weight of the supervisor's large-margin loss (0: off)

    Other parameters: as SB3's ``DQN`` (the replay buffer is :class:`MaskedReplayBuffer`).
    """

    #: DQfD's margin of the supervisor's action over the others (Hester et al. 2018: 0.8)
    SAFETY_MARGIN = 0.8

    def __init__(
        self,
        policy: Any,
        env: GymEnv | str | None,
        *args: Any,
        action_masking: bool = True,
        safety_loss_coef: float = 0.0,
        **kwargs: Any,
    ):
        if (action_masking or safety_loss_coef) and kwargs.get("replay_buffer_class") is None:
            kwargs["replay_buffer_class"] = MaskedReplayBuffer
        super().__init__(policy, env, *args, action_masking=action_masking, safety_loss_coef=safety_loss_coef, **kwargs)

    def safety_loss(self, q_values: th.Tensor, executed: th.Tensor) -> th.Tensor:
        """DQfD's large-margin loss averaged over the rows whose ``executed`` action is >= 0
        (0 without such rows): ``q_values`` (batch, n_actions), ``executed`` (batch,)."""
        chosen = executed >= 0
        if not bool(chosen.any()):
            return q_values.new_zeros(())
        q, labels = q_values[chosen], executed[chosen].long()
        margins = th.full_like(q, self.SAFETY_MARGIN).scatter(1, labels[:, None], 0.0)
        return ((q + margins).max(dim=1).values - q.gather(1, labels[:, None]).squeeze(1)).mean()

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
        if not self.action_masking:
            return super()._sample_action(learning_starts, action_noise, n_envs)
        assert self.env is not None and self._last_obs is not None, "the DQN collects on its env"
        masks = get_action_masks(self.env)
        if self.num_timesteps < learning_starts:
            actions = _random_available(masks)
        else:
            actions, _ = self.predict(self._last_obs, deterministic=False, action_masks=masks)  # type: ignore[arg-type]
        return actions, actions

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:
        """SB3's ``DQN.train`` with the bootstrap target's max over the available next actions."""
        if not self.action_masking and not self.safety_loss_coef:
            return super().train(gradient_steps, batch_size)
        self.policy.set_training_mode(True)
        self._update_learning_rate(self.policy.optimizer)
        losses, safety_losses = [], []
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
                safety_loss = self.safety_loss(q_values, replay_data.executed_actions)
                safety_losses.append(safety_loss.item())
                loss = loss + self.safety_loss_coef * safety_loss
            self.policy.optimizer.zero_grad()
            loss.backward()
            th.nn.utils.clip_grad_norm_(self.policy.parameters(), self.max_grad_norm)
            self.policy.optimizer.step()
        self._n_updates += gradient_steps
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        self.logger.record("train/loss", np.mean(losses))
        if safety_losses:
            self.logger.record("train/safety_loss", np.mean(safety_losses))


def _random_available(masks: np.ndarray) -> np.ndarray:
    """One uniformly random available action per row of ``masks`` (batch, n_actions) bool,
    drawn with numpy's global generator as SB3's DQN exploration (seeded by ``set_random_seed``)."""
    scores = np.random.random_sample(masks.shape)
    return np.where(masks, scores, -1.0).argmax(axis=1)


_with_action_masking(MaskedPPO, MaskablePPO)
_with_action_masking(MaskableACKTR, ACKTR, teacher=False)  # K-FAC steps only on its own loss
_with_action_masking(MaskableDQN, DQN, prior=False)


def per_agent_batches(buffer: Any, parent_get: Any) -> Any:
    """Minibatches of a maskable rollout buffer that are the VecEnv slots: each yields one AV slot's
    ``n_steps`` consecutive transitions, the slots in random order (the authors' MA2C takes one
    optimiser step per AV on that AV's transitions)."""
    if not buffer.generator_ready:
        next(parent_get(None))  # sb3-contrib flattens the arrays slot-major on first use
    for slot in np.random.permutation(buffer.n_envs):
        yield buffer._get_samples(np.arange(slot * buffer.buffer_size, (slot + 1) * buffer.buffer_size))


class PerAgentRolloutBuffer(MaskableRolloutBuffer):
    """sb3-contrib's maskable rollout buffer with one minibatch per AV slot (:func:`per_agent_batches`)."""

    def get(self, batch_size: int | None = None) -> Any:
        return per_agent_batches(self, super().get)


class PerAgentDictRolloutBuffer(MaskableDictRolloutBuffer):
    """The same on Dict observations (``critic: centralised``)."""

    def get(self, batch_size: int | None = None) -> Any:
        return per_agent_batches(self, super().get)


class MaskableA2C(MaskableActorCritic):
    """A2C (SB3's arguments and defaults) with invalid-action masking (see the module doc).

    :param action_masking: sample only available meta-actions (the authors' MA2C) or all of them
    :param rms_prop_eps: RMSprop epsilon (with ``use_rms_prop``; RMSprop alpha 0.99 as SB3's A2C)
    :param use_rms_prop: RMSprop (A2C's original optimiser) rather than Adam
    :param safety_loss_coef: weight of the safety supervisor's teaching loss (:class:`SupervisorTeacher`; 0: off)
    :param prior: ``idm-mobil``: start from the rule driver and regularise toward it
        (:mod:`sb3_marl.algos.rule_prior`, with ``prior_warm_start``, ``prior_coef``,
        ``prior_coef_final``, ``prior_decay_steps``, ``prior_smoothing``); None: off
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
        )

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = ACTOR_CRITIC_POLICIES

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


class SafeTRPO(SafeLoading, TRPO):
    """sb3-contrib's ``TRPO`` (``matrpo``) whose ``load`` never unpickles (:class:`~sb3_marl.loading.SafeLoading`)."""


def uses_action_masks(model: BaseAlgorithm) -> bool:
    """Whether ``model`` acts on action masks (a maskable learner with ``action_masking`` on)."""
    return bool(getattr(model, "action_masking", False))
