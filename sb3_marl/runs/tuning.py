"""Hyperparameter search on the multi-agent scenario with rl_zoo3's Optuna machinery (``train -optimize``).

rl_zoo3 keeps its samplers (TPE, random), pruners (median, halving, none), study storage and
report; :class:`~sb3_marl.runs.experiment.MARLExperimentManager` only changes what a trial trains on
(the ParameterSharingVecEnv) and how it is scored (the paper's metric, by
:class:`~sb3_marl.runs.callbacks.ScenarioEvalCallback`, with the masks and the supervisor as configured).
This module holds the parts rl_zoo3 lacks:

- samplers for MA2C's own keys (rl-zoo's A2C sampler knows neither the authors' RMSprop update
  nor ``per_agent_updates`` and would replace the paper's network) and for ACKTR (none in rl-zoo);
  MAPPO, MADQN and MATRPO use rl-zoo's PPO, DQN and TRPO samplers, their ``net_arch`` /
  ``activation_fn`` going to the layers on top of the paper's trunk;
- :class:`TrialPruningCallback`, which reports each intermediate evaluation to the trial;
- :func:`best_hyperparams_yaml`, the best trial as a ready zoo-config entry.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import optuna
import yaml
from rl_zoo3.hyperparams_opt import HYPERPARAMS_CONVERTER, HYPERPARAMS_SAMPLER
from stable_baselines3.common.callbacks import BaseCallback

Sampler = Callable[[optuna.Trial, int, int, dict], dict[str, Any]]


def sample_actor_critic_params(trial: optuna.Trial) -> dict[str, Any]:
    """Keys shared by MA2C and ACKTR (names as in the zoo configs; n_steps stays one episode)."""
    return {
        "learning_rate": trial.suggest_float("learning_rate", 1e-5, 5e-3, log=True),
        "ent_coef": trial.suggest_float("ent_coef", 1e-4, 0.1, log=True),
        "vf_coef": trial.suggest_float("vf_coef", 0.25, 1.0),
        "gamma": trial.suggest_categorical("gamma", [0.95, 0.98, 0.99, 0.995]),
        "gae_lambda": trial.suggest_categorical("gae_lambda", [0.9, 0.95, 0.98, 1.0]),
    }


def sample_ma2c_params(trial: optuna.Trial, n_actions: int, n_envs: int, additional_args: dict) -> dict[str, Any]:
    """MA2C (the authors' RMSprop A2C with masks): the actor-critic keys, the gradient clip and the
    update cadence (the per-slot one, or one step per rollout at the scaled learning rate). The
    network stays the paper's."""
    return _convert_ma2c(
        {
            **sample_actor_critic_params(trial),
            "max_grad_norm": trial.suggest_categorical("max_grad_norm", [0.5, 1.0, 2.0, 5.0, 10.0]),
            "per_agent_updates": trial.suggest_categorical("per_agent_updates", [True, False]),
        }
    )


def _convert_ma2c(params: dict[str, Any]) -> dict[str, Any]:
    """One step per AV slot, or one per rollout at the learning rate x slots (results/update-cadence/)."""
    return {**params, "scale_lr_by_slots": not params["per_agent_updates"]}


def sample_acktr_params(trial: optuna.Trial, n_actions: int, n_envs: int, additional_args: dict) -> dict[str, Any]:
    """ACKTR: the actor-critic keys (its learning rate is K-FAC's step size, larger) and K-FAC's trust region."""
    params = sample_actor_critic_params(trial)
    params["learning_rate"] = trial.suggest_float("kfac_learning_rate", 1e-3, 1.0, log=True)
    params["kl_clip"] = trial.suggest_float("kl_clip", 1e-4, 1e-2, log=True)
    params["damping"] = trial.suggest_float("damping", 1e-3, 1e-1, log=True)
    return params


def _convert_acktr(params: dict[str, Any]) -> dict[str, Any]:
    params = dict(params)
    params["learning_rate"] = params.pop("kfac_learning_rate")
    return params


#: Learner -> (sampler, converter of a trial's params to hyperparameters).
SAMPLERS: dict[str, tuple[Sampler, Callable[[dict], dict]]] = {
    "ma2c": (sample_ma2c_params, _convert_ma2c),
    "maacktr": (sample_acktr_params, _convert_acktr),
    "acktr": (sample_acktr_params, _convert_acktr),
    "mappo": (HYPERPARAMS_SAMPLER["ppo"], HYPERPARAMS_CONVERTER["ppo"]),
    "madqn": (HYPERPARAMS_SAMPLER["dqn"], HYPERPARAMS_CONVERTER["dqn"]),
    "matrpo": (HYPERPARAMS_SAMPLER["trpo"], HYPERPARAMS_CONVERTER["trpo"]),
}
#: Learner -> the sampled keys that are the config's own: a new study's first trial is the
#: configuration as shipped (when its values lie in the sampled ranges), so the search says whether it beats it.
CONFIG_TRIAL_KEYS: dict[str, tuple[str, ...]] = {
    "ma2c": ("learning_rate", "ent_coef", "vf_coef", "gamma", "gae_lambda", "max_grad_norm", "per_agent_updates"),
}


class TrialPruningCallback(BaseCallback):
    """``callback_after_eval`` of a ScenarioEvalCallback: reports each evaluation's mean return
    to the Optuna trial and stops training when the pruner says so (as rl_zoo3's TrialEvalCallback)."""

    def __init__(self, trial: optuna.Trial) -> None:
        super().__init__()
        self.trial = trial
        self.evaluations = 0
        self.is_pruned = False

    def _on_step(self) -> bool:
        self.evaluations += 1
        self.trial.report(self.parent.last_summary["return_mean"], self.evaluations)  # type: ignore[union-attr]
        self.is_pruned = self.trial.should_prune()
        return not self.is_pruned


def merge_sampled(hyperparams: dict[str, Any], sampled: dict[str, Any]) -> dict[str, Any]:
    """``hyperparams`` updated with a trial's ``sampled`` ones; sampled ``policy_kwargs`` (rl-zoo's
    ``net_arch`` / ``activation_fn``) are merged over the configured ones (the paper's trunk stays)."""
    sampled = dict(sampled)
    policy_kwargs = {**(hyperparams.get("policy_kwargs") or {}), **sampled.pop("policy_kwargs", {})}
    return {**hyperparams, **sampled, "policy_kwargs": policy_kwargs}


def _policy_kwargs_text(policy_kwargs: dict[str, Any]) -> str:
    """rl-zoo's string form of ``policy_kwargs`` (evaluated when the config is read)."""
    items = []
    for key, value in policy_kwargs.items():
        text = f"nn.{value.__name__}" if isinstance(value, type) else repr(value)
        items.append(f"{key}={text}")
    return f"dict({', '.join(items)})"


def best_hyperparams_yaml(algo: str, env_id: str, base: dict[str, Any], params: dict[str, Any], value: float) -> str:
    """A zoo-config entry for ``env_id``: the config's hyperparameters ``base`` (as read from YAML)
    with the best trial's ``params`` converted and written over them."""
    converted = SAMPLERS[algo][1](params)
    sampled_policy_kwargs = converted.pop("policy_kwargs", None)
    entry = {**base, **converted}
    if sampled_policy_kwargs:
        entry["policy_kwargs"] = _policy_kwargs_text(sampled_policy_kwargs)
    header = (
        f"# Best trial of `sb3-marl train --algo {algo} -optimize` on {env_id}: mean evaluation return "
        f"{value:.2f}\n# (the paper's metric). Paste into zoo_configs/{algo}.yml or pass with -c.\n"
    )
    return header + yaml.safe_dump({env_id: entry}, sort_keys=False)


def config_trial(algo: str, hyperparams: dict[str, Any]) -> dict[str, Any] | None:
    """The trial params of the shipped configuration ``hyperparams``, or None if the learner has
    no such mapping or the config lacks a key."""
    keys = CONFIG_TRIAL_KEYS.get(algo, ())
    if not keys or any(key not in hyperparams for key in keys):
        return None
    return {key: hyperparams[key] for key in keys}


__all__ = ["CONFIG_TRIAL_KEYS", "SAMPLERS", "TrialPruningCallback", "best_hyperparams_yaml", "config_trial", "merge_sampled"]
