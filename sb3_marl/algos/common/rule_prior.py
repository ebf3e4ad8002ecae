"""The rule driver as the learners' starting point and regulariser (``prior: idm-mobil``).

The scenario's rule driver (IDM + MOBIL as meta-actions, :meth:`LaneChangeEnv.rule_actions`,
reported per VecEnv slot by ``rule_actions()``) is a safe, good policy available at every state.
A learner with a :class:`RulePrior`:

1. **Warm start by DAgger** (Ross et al. 2011), before reinforcement learning, for ``warm_start``
   AV-steps of its budget: :data:`DAGGER_ITERATIONS` rounds in which the rule driver takes each
   slot's action with probability β = 0.5^round (the policy's sampled action otherwise), the rule
   driver labels every visited state, and the policy is fitted on all states gathered so far:
   the actor to the labels (:func:`prior_loss`), the critic to the discounted returns of what was
   driven (the learner's training rewards, bootstrapped as SB3 does at time limits).
2. **Fine-tuning regularised toward the rule driver** (kickstarting / HR-PPO): the learner's own
   loss plus ``w · prior_loss`` on each update's batch, in the same loss and the same optimiser
   step, with ``w`` falling linearly from ``coef`` to ``coef_final`` over ``decay_steps`` AV-steps
   after the warm start (:meth:`RulePrior.weight`).

``prior_loss`` is the cross-entropy to the rule action smoothed by ``smoothing`` over the
available actions: up to a constant it is KL(π_rule ‖ π) with π_rule = (1 - ε) one-hot + ε
uniform; it is logged as that KL (``train/prior_kl``) with its weight (``train/prior_coef``).
With ``form: agreement`` the fine-tuning's term is instead the expected disagreement with the
rule driver, 1 - Σ π_rule(a) π(a): its pull toward the rule action fades where the policy has
committed to another action, so it does not hold probability on both (the cross-entropy's pull
grows there); the warm start fits the cross-entropy either way.
Timesteps count AV-steps (SB3's ``num_timesteps`` on the parameter-sharing VecEnv), the warm
start's included. MADQN takes the same schedule in DQfD's way (:class:`~sb3_marl.algos.dqn.MaskableDQN`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import torch as th
import torch.nn.functional as F
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper
from stable_baselines3.common.vec_env.base_vec_env import VecEnvStepReturn

from sb3_marl.algos.common.policies import clip_gradients, model_policy
from sb3_marl.algos.common.teacher import MAX_LOSS_WEIGHT, select_rows
from sb3_marl.common.checks import check_integer, check_number, invalid
from sb3_marl.envs.config import with_supervisor
from sb3_marl.evaluation.episodes import evaluate_on_density
from wrappers.step_arrays import current_rule_actions, step_arrays_of

#: Rule drivers a learner can start from: the scenario's IDM/MOBIL decision.
PRIORS = ("idm-mobil",)
#: The fine-tuning's prior term: the cross-entropy to the rule action, or the expected disagreement.
PRIOR_FORMS = ("cross-entropy", "agreement")
#: DAgger rounds of the warm start (β = 0.5 ** round; round 0 is the rule driver alone).
DAGGER_ITERATIONS = 8
#: Passes over the gathered states after each DAgger round, minibatch size and Adam's step size.
DAGGER_EPOCHS, DAGGER_BATCH, DAGGER_LR = 4, 256, 1e-3
#: After each round, the policy alone (sampled actions, no safety supervisor) drives this many
#: episodes, seeds from :data:`DAGGER_EVAL_SEED` on (apart from training and evaluation seeds).
DAGGER_EVAL_EPISODES, DAGGER_EVAL_SEED = 12, 20_000


@dataclass(frozen=True)
class RulePrior:
    """A learner's rule prior (the hyperparameters ``prior``, ``prior_warm_start``, ``prior_coef``,
    ``prior_coef_final``, ``prior_decay_steps``, ``prior_smoothing``, ``prior_form``).

    :param name: the rule driver (one of :data:`PRIORS`), None: off
    :param warm_start: AV-steps of the DAgger warm start (0: none)
    :param coef: weight of the prior loss at the start of reinforcement learning
    :param coef_final: its weight after ``decay_steps`` (the floor)
    :param decay_steps: AV-steps over which the weight falls linearly from ``coef`` to ``coef_final``
    :param smoothing: ε of the smoothed rule action, in [0, 1) (0: the rule action itself; the loss
        is then -log π(rule action | s))
    :param form: the fine-tuning's term, one of :data:`PRIOR_FORMS` (see the module doc)
    """

    name: str | None = None
    warm_start: int = 0
    coef: float = 1.0
    coef_final: float = 0.0
    decay_steps: int = 1
    smoothing: float = 0.0
    form: str = "cross-entropy"

    @classmethod
    def from_kwargs(cls, kwargs: dict[str, Any]) -> RulePrior:
        """The prior of a learner's keyword arguments (``prior``, ``prior_<field>``), validated."""
        return cls(**{key.removeprefix("prior_") if key != "prior" else "name": value for key, value in kwargs.items()})

    def __post_init__(self) -> None:
        if self.name is not None and self.name not in PRIORS:
            raise invalid("prior", self.name, f"one of {list(PRIORS)} (or null: off)")
        check_integer("prior_warm_start", self.warm_start, 0, expected="an integer >= 0 (AV-steps)")
        check_integer("prior_decay_steps", self.decay_steps, 1, expected="an integer >= 1 (AV-steps)")
        check_number("prior_coef", self.coef, 0, MAX_LOSS_WEIGHT)
        check_number("prior_coef_final", self.coef_final, 0, MAX_LOSS_WEIGHT)
        check_number("prior_smoothing", self.smoothing, 0, 1, high_open=True, expected="a number in [0, 1)")
        if self.form not in PRIOR_FORMS:
            raise invalid("prior_form", self.form, f"one of {list(PRIOR_FORMS)}")

    @property
    def active(self) -> bool:
        return self.name is not None

    def weight(self, timesteps: int) -> float:
        """The prior loss's weight after ``timesteps`` AV-steps (0 when off)."""
        if not self.active:
            return 0.0
        progress = min(max(timesteps - self.warm_start, 0) / self.decay_steps, 1.0)
        return float(self.coef + (self.coef_final - self.coef) * progress)

    def as_kwargs(self) -> dict[str, Any]:
        """The learner's keyword arguments of this prior."""
        return {f"prior_{key}" if key != "name" else "prior": value for key, value in asdict(self).items()}


def smoothed_targets(labels: th.Tensor, smoothing: float, available: th.Tensor) -> th.Tensor:
    """(batch, actions) the rule actions ``labels`` (batch,) as distributions: 1 - ``smoothing`` on
    the label plus ``smoothing`` spread evenly over the ``available`` actions (bool)."""
    spread = available.float() * (smoothing / available.sum(dim=1, keepdim=True).clamp(min=1))
    own = th.full((labels.shape[0], 1), 1 - smoothing, dtype=spread.dtype, device=spread.device)
    return spread.scatter_add(1, labels.long()[:, None], own)


def prior_loss(
    logits: th.Tensor, labels: th.Tensor, smoothing: float, masks: th.Tensor | None = None, form: str = "cross-entropy"
) -> tuple[th.Tensor, th.Tensor]:
    """(mean loss, mean KL(π_rule ‖ π) without gradient) of the policy's ``logits`` (batch,
    actions) to the rule actions ``labels`` smoothed by ``smoothing`` over the available actions
    (``masks``, bool; None: all); the loss is the cross-entropy, or with ``form`` ``agreement``
    the expected disagreement 1 - Σ π_rule(a) π(a)."""
    available = th.ones_like(logits, dtype=th.bool) if masks is None else masks.bool()
    target = smoothed_targets(labels, smoothing, available)
    log_probs = F.log_softmax(logits.masked_fill(~available, -1e8), dim=1)
    cross_entropy = -(target * log_probs).sum(dim=1).mean()
    with th.no_grad():
        entropy = -(target * th.log(target.clamp(min=1e-12))).sum(dim=1).mean()
    kl = cross_entropy.detach() - entropy
    if form == "agreement":
        return 1 - (target * log_probs.exp()).sum(dim=1).mean(), kl
    return cross_entropy, kl


def masked_logits(policy: Any, observations: Any, action_masks: Any) -> th.Tensor:
    """The policy's action logits of ``observations`` (masked where ``action_masks`` is given)."""
    distribution = policy.get_distribution(observations, action_masks=action_masks)
    return distribution.distribution.logits


class RuleLabels(VecEnvWrapper):
    """Records, per step and slot, the rule driver's action for the observation acted on
    (``labels[step]``); with ``beta`` > 0, each slot executes it instead of the given action with
    probability ``beta`` (DAgger's mixture)."""

    def __init__(self, venv: VecEnv, n_steps: int, beta: float = 0.0, rng: np.random.Generator | None = None) -> None:
        super().__init__(venv)
        self.labels = np.full((n_steps, venv.num_envs), -1, dtype=np.int64)
        self.executed = np.zeros((n_steps, venv.num_envs), dtype=np.int64)
        self.beta, self.rng, self.position = beta, rng or np.random.default_rng(), 0

    def reset(self) -> Any:
        return self.venv.reset()

    def step_async(self, actions: np.ndarray) -> None:
        labels = current_rule_actions(self.venv)
        actions = np.asarray(actions).reshape(-1)
        if self.beta > 0:
            actions = np.where(self.rng.random(actions.size) < self.beta, labels, actions)
        if self.position < len(self.labels):
            self.labels[self.position], self.executed[self.position] = labels, actions
        self.position += 1
        self.venv.step_async(actions)

    def step_wait(self) -> VecEnvStepReturn:
        return self.venv.step_wait()


def dagger(model: Any, timesteps: int, prior: RulePrior) -> None:
    """The DAgger warm start of an actor-critic ``model`` on its own VecEnv for about ``timesteps``
    AV-steps (see the module doc); advances ``model.num_timesteps`` and logs each round under
    ``dagger/``: ``beta``, ``agreement`` (share of visited states where the policy's most likely
    action is the rule action, before the round's fit), ``collision_rate`` (share of the round's
    finished episodes that ended in a crash, the scenario's supervisor as configured),
    ``episode_return`` (mean slot return of those, in the reward mode), ``prior_loss`` and
    ``value_loss`` (after the fit), and the policy alone after the fit (sampled actions, no
    supervisor, :data:`DAGGER_EVAL_EPISODES` episodes): ``alone/collision_rate`` and
    ``alone/episode_return`` (the paper's return)."""
    env, policy = model.env, model.policy
    env_id, config = env.get_attr("spec", [0])[0].id, env.get_attr("config", [0])[0]
    n_envs = env.num_envs
    steps = max(timesteps // (DAGGER_ITERATIONS * n_envs), 1)
    rng = np.random.default_rng(model.seed)
    optimizer = th.optim.Adam(policy.parameters(), lr=DAGGER_LR)
    gathered: dict[str, list[np.ndarray]] = {"obs": [], "masks": [], "labels": [], "returns": []}
    obs = model._last_obs
    for iteration in range(DAGGER_ITERATIONS):
        beta = 0.5**iteration
        mixed = RuleLabels(env, steps, beta, rng)
        rewards, dones, masks, observations = [], [], [], []
        crashes, ended, returns = 0, 0, []
        for _ in range(steps):
            step_masks = np.stack(env.env_method("action_masks"))
            with th.no_grad():
                actions, _, _ = policy(policy.obs_to_tensor(obs)[0], action_masks=step_masks)
            observations.append(obs)
            masks.append(step_masks)
            obs, reward, done, infos = mixed.step(actions.cpu().numpy())
            arrays = step_arrays_of(mixed)  # an ended episode counts once: at its first AV's slot
            first_av = np.ones(n_envs, dtype=bool) if arrays is None else arrays.agent == 0
            for slot, info in enumerate(infos):
                if done[slot] and info.get("TimeLimit.truncated", False):
                    reward[slot] += model.gamma * _value(policy, info["terminal_observation"])[0]
                if done[slot] and first_av[slot]:
                    ended += 1
                    crashes += not info.get("TimeLimit.truncated", False)
                if "episode" in info:
                    returns.append(info["episode"]["r"])
            rewards.append(reward)
            dones.append(done)
        model.num_timesteps += steps * n_envs
        discounted = _discounted_returns(np.array(rewards), np.array(dones), _value(policy, obs), model.gamma)
        flat_obs = _concat(observations)
        labels = mixed.labels.reshape(-1)
        agreement = _agreement(policy, flat_obs, np.concatenate(masks), labels)
        round_data = {"obs": flat_obs, "masks": np.concatenate(masks), "labels": labels, "returns": discounted.reshape(-1)}
        for key, value in round_data.items():
            gathered[key].append(value)
        losses = _fit(model, optimizer, {key: _concat(values) for key, values in gathered.items()}, prior.smoothing, rng)
        seed = DAGGER_EVAL_SEED + iteration * DAGGER_EVAL_EPISODES
        alone = evaluate_on_density(model_policy(model), env_id, DAGGER_EVAL_EPISODES, seed, with_supervisor(config, "off"))
        for key, value in (
            ("beta", beta),
            ("agreement", agreement),
            ("collision_rate", crashes / ended if ended else float("nan")),
            ("episode_return", float(np.mean(returns)) if returns else float("nan")),
            ("prior_loss", losses[0]),
            ("value_loss", losses[1]),
            ("alone/collision_rate", alone["collision_rate"]),
            ("alone/episode_return", alone["return_mean"]),
        ):
            model.logger.record(f"dagger/{key}", value)
        model.logger.dump(step=model.num_timesteps)
        if model.verbose >= 1:
            print(
                f"DAgger warm start, round {iteration + 1}/{DAGGER_ITERATIONS}: {model.num_timesteps} AV-steps, "
                f"agreement with the rule driver {agreement:.2f}; the policy alone: return {alone['return_mean']:.2f}, "
                f"collision rate {alone['collision_rate']:.2f} ({DAGGER_EVAL_EPISODES} episodes)",
                flush=True,
            )
    model._last_obs = obs
    model._last_episode_starts = np.asarray(dones[-1], dtype=bool)


def _value(policy: Any, obs: Any) -> Any:
    with th.no_grad():
        return policy.predict_values(policy.obs_to_tensor(obs)[0]).cpu().numpy().reshape(-1)


def _discounted_returns(rewards: np.ndarray, dones: np.ndarray, last_values: np.ndarray, gamma: float) -> np.ndarray:
    """(steps, slots) discounted returns; an episode's end (``dones``) stops the sum, the round's
    end is bootstrapped with ``last_values``."""
    returns = np.zeros_like(rewards, dtype=np.float32)
    following = last_values
    for t in reversed(range(len(rewards))):
        following = rewards[t] + gamma * following * (1 - dones[t])
        returns[t] = following
    return returns


def _concat(values: list[Any]) -> Any:
    if isinstance(values[0], dict):
        return {key: np.concatenate([v[key] for v in values]) for key in values[0]}
    return np.concatenate(values)


def _agreement(policy: Any, obs: Any, masks: np.ndarray, labels: np.ndarray) -> float:
    with th.no_grad():
        logits = masked_logits(policy, policy.obs_to_tensor(obs)[0], masks)
    return float((logits.argmax(dim=1).cpu().numpy() == labels).mean())


def _fit(
    model: Any, optimizer: th.optim.Optimizer, data: dict[str, Any], smoothing: float, rng: np.random.Generator
) -> tuple[float, float]:
    """Passes of minibatch Adam over ``data``: the actor to the labels, the critic to the returns
    (weighted by the learner's ``vf_coef``); returns the last pass's mean prior and value losses."""
    policy = model.policy
    policy.set_training_mode(True)
    n = len(data["labels"])
    for _ in range(DAGGER_EPOCHS):
        prior_losses, value_losses = [], []
        order = rng.permutation(n)
        for start in range(0, n, DAGGER_BATCH):
            rows = order[start : start + DAGGER_BATCH]
            obs = policy.obs_to_tensor(select_rows(data["obs"], rows))[0]
            masks = th.as_tensor(data["masks"][rows], device=policy.device)
            labels = th.as_tensor(data["labels"][rows], device=policy.device)
            imitation, _ = prior_loss(masked_logits(policy, obs, masks), labels, smoothing, masks)
            value = F.mse_loss(policy.predict_values(obs).flatten(), th.as_tensor(data["returns"][rows], device=policy.device))
            optimizer.zero_grad()
            (imitation + model.vf_coef * value).backward()
            clip_gradients(optimizer, model.max_grad_norm)
            optimizer.step()
            prior_losses.append(imitation.item())
            value_losses.append(value.item())
    policy.set_training_mode(False)
    return float(np.mean(prior_losses)), float(np.mean(value_losses))


def prior_term(model: Any, observations: Any, action_masks: Any, indices: np.ndarray, logs: dict[str, list]) -> Any:
    """``w · prior_loss`` of the rollout's samples at ``indices`` (of the flattened, slot-major
    buffer), 0 without labels; logs the loss, its KL and the weight."""
    weight = model.rule_prior.weight(model.num_timesteps)
    rule_labels = model.rollout_extras.rule_labels
    if rule_labels is None or weight <= 0:
        return 0.0
    policy = model.policy
    labels = th.as_tensor(rule_labels.swapaxes(0, 1).reshape(-1)[indices], device=policy.device)
    logits = masked_logits(policy, observations, action_masks)
    loss, kl = prior_loss(logits, labels, model.prior_smoothing, action_masks, model.prior_form)
    logs["prior_loss"].append(loss.item())
    logs["prior_kl"].append(kl.item())
    logs["prior_coef"].append(weight)
    return weight * loss
