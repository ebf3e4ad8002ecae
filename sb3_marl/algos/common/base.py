"""What the maskable learners share: the policies of the actor-critics, the base of the on-policy
ones (:class:`MaskableOnPolicy`) and the keyword arguments a learner takes (:func:`hyperparameters`).

The scenario env says which meta-actions each AV may take (``action_masks()``: FASTER only below
the top target speed, a lane change only towards a reachable lane, ...); the parameter-sharing
VecEnv passes those masks per AV slot; the rollout (:meth:`MaskableOnPolicy.collect_rollouts`, the
policy's forward in numpy: :mod:`~sb3_marl.algos.common.numpy_forward`) and sb3-contrib's maskable
policy, distribution and rollout buffer do the rest. The learners, one per module: MA2C (``a2c``: A2C's update on the maskable
machinery), MAPPO (``ppo``), MAACKTR (``acktr``), MADQN (``dqn``: SB3's DQN with masked greedy
actions, exploration and bootstrap targets), MATRPO (``trpo``). All maskable learners take
``action_masking`` (default True): False trains and acts without masks (the unmasked learner of
the ablation) with the same network; ``predict(obs, action_masks=...)`` takes masks exactly as
sb3-contrib's maskable algorithms do.
"""

from __future__ import annotations

import inspect
from typing import Any, ClassVar, NamedTuple

import numpy as np
import torch as th
from sb3_contrib import MaskablePPO
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.utils import obs_as_tensor

from sb3_marl.algos.common.loading import safe_load
from sb3_marl.algos.common.numpy_forward import NumpyActorCritic
from sb3_marl.algos.common.policies import CentralisedCriticPolicy
from sb3_marl.algos.common.rule_prior import RulePrior, dagger, prior_term
from sb3_marl.algos.common.teacher import check_safety_loss_coef, executed_labels, safety_step
from wrappers.step_arrays import current_action_masks, current_rule_actions, stack_observations, step_arrays_of

#: Policies of the maskable actor-critic learners: sb3-contrib's, plus the centralised critic
#: (``critic: centralised``, selected by the hyperparameters under this alias).
ACTOR_CRITIC_POLICIES: dict[str, type[BasePolicy]] = {
    **MaskablePPO.policy_aliases,
    CentralisedCriticPolicy.__name__: CentralisedCriticPolicy,
}


def hyperparameters(cls: type) -> dict[str, inspect.Parameter]:
    """The keyword arguments a learner class takes: those of its own ``__init__`` and of each class
    up its MRO that the arguments are passed on to (``**kwargs``), down to the first that takes no
    more (SB3's algorithm), less those the class leaves out (``left_out``)."""
    found: dict[str, inspect.Parameter] = {}
    for klass in cls.__mro__:
        if "__init__" not in vars(klass):
            continue
        parameters = list(inspect.signature(klass.__init__).parameters.values())[1:]  # type: ignore[misc]
        skipped = (inspect.Parameter.VAR_POSITIONAL, inspect.Parameter.VAR_KEYWORD)
        found.update({p.name: p for p in parameters if p.kind not in skipped and p.name not in found})
        if all(p.kind != inspect.Parameter.VAR_KEYWORD for p in parameters):
            break
    return {name: p for name, p in found.items() if name not in getattr(cls, "left_out", ())}


class RolloutExtras(NamedTuple):
    """What a rollout records beside SB3's buffer for the extra loss terms, (n_steps, n_envs) as
    the buffer's arrays (None where the term is off)."""

    rule_labels: np.ndarray | None  # the rule driver's action for each observation (the prior's labels)
    executed: np.ndarray | None  # the supervisor's action where it replaced the policy's, -1 elsewhere (the teacher's)


class MaskableOnPolicy(OnPolicyAlgorithm):
    """What the maskable on-policy learners (MA2C, MAPPO, MAACKTR) add to their base (sb3-contrib's
    ``MaskablePPO``, our ``ACKTR``), as switches and terms of one update:

    - ``action_masking``: masked rollouts (:meth:`collect_rollouts`) and
      ``predict(..., action_masks=...)``, with masks only when it is True;
    - the rule prior (``prior``, ``prior_*``: :class:`~sb3_marl.algos.common.rule_prior.RulePrior`):
      the DAgger warm start when learning starts, the rule driver's labels of each rollout and the
      prior's term of the loss (:meth:`prior_term`);
    - the safety teacher (``safety_loss_coef``): the supervisor's interventions recorded during
      each rollout, and one more optimiser step after each update (:meth:`safety_step`).

    The settings are saved with the model (plain attributes, with the class name as
    ``algorithm_class``: loading a model as another algorithm is refused by name,
    :func:`sb3_marl.runs.folders.check_model_file`); ``load`` never unpickles
    (:data:`~sb3_marl.algos.common.loading.safe_load`).
    """

    load = safe_load
    #: keywords of the terms above that a learner's update does not take (refused when set)
    left_out: ClassVar[tuple[str, ...]] = ()
    action_masking: bool = True
    safety_loss_coef: float = 0.0
    # set by __init__ from a validated RulePrior (its defaults are the only ones)
    prior: str | None
    prior_warm_start: int
    prior_coef: float
    prior_coef_final: float
    prior_decay_steps: int
    prior_smoothing: float
    prior_form: str
    rollout_extras: RolloutExtras = RolloutExtras(None, None)

    def __init__(
        self,
        *args: Any,
        action_masking: bool = True,
        safety_loss_coef: float = 0.0,
        prior: str | None = None,
        prior_warm_start: int = 0,
        prior_coef: float = 1.0,
        prior_coef_final: float = 0.0,
        prior_decay_steps: int = 1,
        prior_smoothing: float = 0.0,
        prior_form: str = "cross-entropy",
        **kwargs: Any,
    ) -> None:
        self.safety_loss_coef = check_safety_loss_coef(safety_loss_coef)
        if self.safety_loss_coef and "safety_loss_coef" in self.left_out:
            raise ValueError(f"Invalid safety_loss_coef={safety_loss_coef!r}: {type(self).__name__} has no teacher's step.")
        settings = RulePrior(
            prior, prior_warm_start, prior_coef, prior_coef_final, prior_decay_steps, prior_smoothing, prior_form
        )
        self.__dict__.update(settings.as_kwargs())
        self.algorithm_class = type(self).__name__
        self.action_masking = bool(action_masking)
        super().__init__(*args, **kwargs)

    @property
    def rule_prior(self) -> RulePrior:
        return RulePrior.from_kwargs({key: getattr(self, key) for key in RulePrior().as_kwargs()})

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "rollout_extras"]

    def _setup_learn(self, *args: Any, **kwargs: Any) -> Any:
        """SB3's set-up, then the DAgger warm start where the budget's first ``prior_warm_start``
        AV-steps are still ahead (no further than the budget: a budget below the warm start is all
        warm start)."""
        result = super()._setup_learn(*args, **kwargs)
        prior = self.rule_prior
        warm_start = min(prior.warm_start, result[0])  # result[0]: the budget's total AV-steps
        if prior.active and self.num_timesteps < warm_start:
            if warm_start < prior.warm_start and self.verbose >= 1:
                print(
                    f"The budget ({warm_start} AV-steps) ends within the DAgger warm start (prior_warm_start "
                    f"{prior.warm_start}): the model will be the rule driver's imitation, with no reinforcement learning",
                    flush=True,
                )
            dagger(self, warm_start - self.num_timesteps, prior)
        return result

    def collect_rollouts(
        self, env: Any, callback: Any, rollout_buffer: Any, n_rollout_steps: int, use_masking: bool = True
    ) -> bool:
        """Fill ``rollout_buffer`` with ``n_rollout_steps`` steps of every slot, as sb3-contrib's
        masked rollout does (masks of each observation, SB3's bootstrap of time-limit truncations
        from the critic, callbacks after each step), with the policy's forward in numpy where it
        has one (:class:`~sb3_marl.algos.common.numpy_forward.NumpyActorCritic`: sampling from a
        generator seeded by the model's seed and timestep), and the rollout's extras for the loss
        terms (:class:`RolloutExtras`: the rule driver's labels, the supervisor's interventions)."""
        masked = use_masking and self.action_masking
        forward = NumpyActorCritic.of(self.policy)
        rng = np.random.default_rng(None if self.seed is None else [self.seed, self.num_timesteps])
        n_envs = env.num_envs
        labels = (
            np.full((n_rollout_steps, n_envs), -1, dtype=np.int64) if self.rule_prior.weight(self.num_timesteps) > 0 else None
        )
        executed = np.full((n_rollout_steps, n_envs), -1, dtype=np.int64) if self.safety_loss_coef > 0 else None
        self.rollout_extras = RolloutExtras(labels, executed)
        self.policy.set_training_mode(False)
        rollout_buffer.reset()
        callback.on_rollout_start()
        for step in range(n_rollout_steps):
            action_masks = current_action_masks(env) if masked else None
            if labels is not None:
                labels[step] = current_rule_actions(env)
            if forward is not None:
                actions, values, log_probs = forward(self._last_obs, action_masks, rng)
            else:
                with th.no_grad():
                    tensors = obs_as_tensor(self._last_obs, self.device)  # type: ignore[arg-type]
                    actions, values, log_probs = (x.cpu().numpy() for x in self.policy(tensors, action_masks=action_masks))
            new_obs, rewards, dones, infos = env.step(actions)
            self.num_timesteps += n_envs
            callback.update_locals(locals())
            if not callback.on_step():
                return False
            if executed is not None:
                executed[step] = executed_labels(step_arrays_of(env), n_envs)
            self._update_info_buffer(infos, dones)
            truncated = [i for i in np.flatnonzero(dones) if infos[i].get("TimeLimit.truncated", False)]
            if truncated:  # SB3's bootstrap of a time limit from the critic, all slots in one call
                terminal = stack_observations([infos[i]["terminal_observation"] for i in truncated])
                rewards[truncated] += self.gamma * self._values(forward, terminal)
            rollout_buffer.add(
                self._last_obs,
                actions.reshape(-1, 1),
                rewards,
                self._last_episode_starts,
                th.as_tensor(values, dtype=th.float32).reshape(-1, 1),
                th.as_tensor(log_probs, dtype=th.float32),
                action_masks=action_masks,
            )
            self._last_obs, self._last_episode_starts = new_obs, dones
        last_values = th.as_tensor(self._values(forward, new_obs), dtype=th.float32).reshape(-1, 1)
        rollout_buffer.compute_returns_and_advantage(last_values=last_values, dones=dones)
        callback.update_locals(locals())
        callback.on_rollout_end()
        return True

    def _values(self, forward: NumpyActorCritic | None, obs: Any) -> np.ndarray:
        """(batch,) the critic's values of observations ``obs``."""
        if forward is not None:
            return forward.values(obs)
        with th.no_grad():
            return self.policy.predict_values(obs_as_tensor(obs, self.device)).cpu().numpy()[:, 0]

    def prior_term(self, observations: Any, action_masks: Any, indices: np.ndarray, logs: dict[str, list]) -> Any:
        """The rule prior's term of the update's loss (:func:`~sb3_marl.algos.common.rule_prior.prior_term`)."""
        return prior_term(self, observations, action_masks, indices, logs)

    def safety_step(self, executed: np.ndarray) -> float:
        """The teacher's step after an update (:func:`~sb3_marl.algos.common.teacher.safety_step`)."""
        return safety_step(self, executed)

    def predict(  # type: ignore[override]  # plus sb3-contrib's action_masks
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
        return self.policy.predict(observation, state, episode_start, deterministic, action_masks=masks)  # type: ignore[call-arg]
