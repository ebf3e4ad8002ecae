"""Trained runs in rl-zoo's log layout: ``<folder>/<algo>/<env name>_<exp id>/``.

A run folder holds the final model ``<env name>.zip``, ``best_model.zip``, checkpoints
``rl_model_<steps>_steps.zip``, ``evaluations.npz``, ``monitor.csv`` and ``<env name>/config.yml``
(the hyperparameters, scenario keys included) and ``<env name>/args.yml``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from rl_zoo3.utils import EnvironmentName, get_latest_run_id, get_model_path
from stable_baselines3.common.base_class import BaseAlgorithm

from sb3_marl.algos import get_algo
from sb3_marl.evaluation import evaluation_records, model_policy, protocol_label, summarize


@dataclass
class Run:
    """One trained run: where its model is and the hyperparameters it was trained with."""

    algo: str
    env_id: str
    log_path: Path
    model_path: Path
    hyperparams: dict[str, Any] = field(default_factory=dict)

    @property
    def env_config(self) -> dict[str, Any]:
        """The scenario overrides of the run (``env_config`` of its config)."""
        return dict(self.hyperparams.get("env_config") or {})

    def load_model(self, device: str = "auto") -> BaseAlgorithm:
        return get_algo(self.algo).load(self.model_path, device=device)

    def evaluate(self, model: BaseAlgorithm, n_episodes: int, seed: int, deterministic: bool = False) -> dict[str, Any]:
        """The paper's metrics of ``model`` on ``n_episodes`` seeded episodes of the run's scenario,
        with what identifies the evaluation (algo, env, timesteps, seeds, env config, protocol:
        sampled actions by default, the authors') and each return."""
        records = evaluation_records(model_policy(model, deterministic), self.env_id, n_episodes, seed, self.env_config)
        return {
            "algo": self.algo, "env_id": self.env_id, "num_timesteps": int(model.num_timesteps),
            "deterministic": deterministic, "protocol": protocol_label(deterministic, model), "seeds": [seed, seed + n_episodes - 1], "env_config": self.env_config,
            **summarize(records), "returns": [r.episode_return for r in records],
        }


def find_run(
    folder: str | Path,
    algo: str,
    env_id: str,
    exp_id: int = 0,
    load_best: bool = False,
    load_checkpoint: int | None = None,
    load_last_checkpoint: bool = False,
) -> Run:
    """The run ``exp_id`` (0: the latest) of ``algo`` on ``env_id`` under ``folder``, with the model
    picked as rl_zoo3's ``enjoy`` does (final, ``--load-best``, ``--load-checkpoint N``, last checkpoint).

    :raises FileNotFoundError: naming the missing folder or model file
    """
    env_name = EnvironmentName(env_id)
    algo_folder = os.path.join(folder, algo)
    if exp_id == 0:
        exp_id = get_latest_run_id(algo_folder, env_name)
        if exp_id == 0:
            raise FileNotFoundError(f"No run of {algo} on {env_id} in {algo_folder}/ (expected {env_name}_<id>/ folders).")
    try:
        _, model_path, log_path = get_model_path(
            exp_id, str(folder), algo, env_name, load_best,
            None if load_checkpoint is None else str(load_checkpoint), load_last_checkpoint,
        )
    except (AssertionError, ValueError) as error:
        raise FileNotFoundError(str(error)) from None
    config_path = Path(log_path) / str(env_name) / "config.yml"
    hyperparams: dict[str, Any] = {}
    if config_path.is_file():
        # rl_zoo3 writes config.yml with yaml.dump(OrderedDict), read back with the unsafe loader as rl_zoo3 does
        hyperparams = dict(yaml.load(config_path.read_text(), Loader=yaml.UnsafeLoader) or {})
    return Run(algo, env_id, Path(log_path), Path(model_path), hyperparams)


def run_folders(folder: str | Path, algo: str, env_id: str) -> list[Path]:
    """All run folders of ``algo`` on ``env_id`` under ``folder``, by run id."""
    prefix = f"{EnvironmentName(env_id)}_"
    algo_folder = Path(folder) / algo
    if not algo_folder.is_dir():
        return []
    runs = [p for p in algo_folder.iterdir() if p.is_dir() and p.name.startswith(prefix) and p.name[len(prefix):].isdigit()]
    return sorted(runs, key=lambda p: int(p.name[len(prefix):]))


__all__ = ["Run", "find_run", "run_folders"]
