"""Build the VecEnv and the model of a learner from its rl-zoo-style hyperparameters."""

from __future__ import annotations

import os
from typing import Any

from rl_zoo3.exp_manager import ExperimentManager
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.vec_env import VecEnv, VecMonitor

from sb3_marl.algos import get_algo
from sb3_marl.envs import av_counts
from sb3_marl.runs.hyperparams import (
    SCENARIO_KEYS,
    ZOO_KEYS,
    is_centralised,
    policy_for,
    policy_kwargs_for,
    validate_hyperparams,
)
from wrappers import ParameterSharingVecEnv, VecCentralisedState, VecRewardScale


def make_venv(
    env_id: str,
    hyperparams: dict[str, Any],
    seed: int,
    vec_backend: str = "dummy",
    monitor_dir: str | None = None,
    monitor_file: str = "monitor.csv",
) -> VecEnv:
    """The parameter-sharing VecEnv of the scenario, with the entry's reward mode, copies,
    scenario overrides, intervention penalty and reward scale, and with ``critic: centralised``
    each slot's copy's global state (:class:`~wrappers.VecCentralisedState`); with ``monitor_dir``, SB3's
    VecMonitor writes each AV's
    episodes (unscaled return, length) to ``<monitor_dir>/<monitor_file>``, as rl_zoo3 expects (SB3's
    ``load_results`` reads every ``*monitor.csv`` of a folder)."""
    venv: VecEnv = ParameterSharingVecEnv(
        env_id,
        n_copies=hyperparams.get("n_copies"),
        reward_mode=hyperparams.get("reward_mode", "local"),
        vec_backend=vec_backend,
        seed=seed,
        config=hyperparams.get("env_config"),
        supervisor_dropout=hyperparams.get("supervisor_dropout", 0.0),
    )
    if is_centralised(hyperparams):
        venv = VecCentralisedState(venv, max(av_counts(env_id, hyperparams.get("env_config"))))
    if monitor_dir is not None:
        os.makedirs(monitor_dir, exist_ok=True)
        monitor = os.path.join(monitor_dir, monitor_file)
        try:
            venv = VecMonitor(venv, monitor)
        except OSError as error:  # SB3's header write names no file (a full disk)
            error.filename = error.filename or monitor
            venv.close()
            raise
    scale, penalty = hyperparams.get("reward_scale", 1.0), hyperparams.get("intervention_penalty", 0.0)
    if scale != 1.0 or penalty:
        venv = VecRewardScale(venv, scale, penalty)
    return venv


def make_model(
    algo: str, venv: VecEnv, hyperparams: dict[str, Any], seed: int, device: str = "cpu", **kwargs: Any
) -> BaseAlgorithm:
    """The algorithm registered as ``algo`` on ``venv``, with the entry's constructor arguments
    and MA2C network; ``kwargs`` (e.g. ``tensorboard_log``, ``verbose``) go to the constructor."""
    validate_hyperparams(algo, hyperparams)
    arguments = {key: value for key, value in hyperparams.items() if key not in (*SCENARIO_KEYS, *ZOO_KEYS, "policy_kwargs")}
    arguments = ExperimentManager._preprocess_schedules(arguments)  # "lin_5e-4" -> a schedule, as rl_zoo3 does
    arguments["policy_kwargs"] = policy_kwargs_for(algo, hyperparams)
    policy = policy_for(hyperparams)
    return get_algo(algo)(policy, venv, seed=seed, device=device, **arguments, **kwargs)
