"""Runs: what one training run is (:class:`RunSpec`), and trained runs in rl-zoo's log layout,
``<folder>/<algo>/<env name>_<exp id>/``.

A run folder holds the final model ``<env name>.zip``, ``best_model.zip``, checkpoints
``rl_model_<steps>_steps.zip``, ``evaluations.npz``, ``monitor.csv`` and ``<env name>/config.yml``
(the hyperparameters, scenario keys included) and ``<env name>/args.yml``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from rl_zoo3.utils import EnvironmentName, get_model_path
from stable_baselines3.common.base_class import BaseAlgorithm

from sb3_marl.algos import ALGO_NAMES, get_algo
from sb3_marl.algos.common.loading import UnsafeModelError, read_model_data, saved_policy_class
from sb3_marl.algos.common.policies import model_policy, uses_action_masks
from sb3_marl.common.files import inside, read_json_object, read_run_yaml
from sb3_marl.envs import scenario_of
from sb3_marl.envs.config import supervisor_version
from sb3_marl.evaluation import evaluate_protocols, protocol_label
from sb3_marl.runs.hyperparams import validate_hyperparams


@dataclass
class RunSpec:
    """One training run, as ``sb3-marl train`` and a benchmark trial both describe it; what
    :class:`MARLExperimentManager` takes, saved as the run's ``args.yml``. Fields keep the names of
    rl-zoo's flags (``train --help``); timesteps and frequencies count AV-steps.

    :param n_envs: scenario copies, overriding the config's ``n_copies`` (None: the config's)
    :param reward_mode: ``local``, ``global`` or ``individual``, overriding the config's (None: the config's)
    :param vec_env: ``dummy`` (copies in process) or ``subproc`` (one worker process per core)
    :param tensorboard_log: TensorBoard folder; None: ``<log_folder>/tensorboard``, "": none
    :param trust_remote_code: continue training (``-i``) from a zip that needs unpickling, and load
        a ``replay_buffer.pkl`` beside it (a pickle); off: the zip is read as data
        (:mod:`sb3_marl.algos.common.loading`) and only a ``replay_buffer.npz`` beside it is loaded
    :param run_id: write to ``<env>_<run_id>/`` (an existing folder is continued) instead of the next free id
    :param monitor_file: name of the training episodes' monitor file in the run folder
    :param evaluate_at_end: evaluate the final model too (if the last evaluation was not at the last step)
    :param save_replay_buffer: write an off-policy learner's replay buffer beside the final model
        (``replay_buffer.npz``, data; ``-i`` continues with it)
    """

    algo: str
    env: str
    log_folder: str = "logs"
    seed: int = 0
    n_timesteps: int = -1
    eval_freq: int = 10_000
    eval_episodes: int = 5
    save_freq: int = -1
    hyperparams: dict[str, Any] = field(default_factory=dict)
    trained_agent: str = ""
    conf_file: str | None = None
    n_envs: int | None = None
    reward_mode: str | None = None
    vec_env: str = "dummy"
    tensorboard_log: str | None = None
    log_interval: int = -1
    verbose: int = 1
    device: str = "auto"
    progress: bool = False
    trust_remote_code: bool = False
    run_id: int | None = None
    monitor_file: str = "monitor.csv"
    evaluate_at_end: bool = False
    save_replay_buffer: bool = False
    # rl-zoo's -optimize (Optuna)
    optimize_hyperparameters: bool = False
    n_trials: int = 500
    n_jobs: int = 1
    sampler: str = "tpe"
    pruner: str = "median"
    n_startup_trials: int = 10
    n_evaluations: int | None = None
    storage: str | None = None
    study_name: str | None = None

    @classmethod
    def from_args(cls, args: Any) -> RunSpec:
        """The run of ``sb3-marl train``'s parsed arguments (the flags this class has fields for)."""
        return cls(**{f.name: getattr(args, f.name) for f in fields(cls) if hasattr(args, f.name)})

    @property
    def tensorboard_folder(self) -> str:
        """Where TensorBoard logs go ("" : nowhere)."""
        return os.path.join(self.log_folder, "tensorboard") if self.tensorboard_log is None else self.tensorboard_log


def check_observation_shape(model: BaseAlgorithm, path: str | Path, env_id: str, config: dict[str, Any]) -> None:
    """A ValueError naming ``path`` unless the model observes what ``env_id`` with ``config``
    shows each AV (its per-AV observation shape: vehicles × features)."""
    import gymnasium as gym
    from gymnasium import spaces

    from sb3_marl.envs import default_config
    from sb3_marl.envs.observation import LOCAL_KEY, observation_space

    density = (gym.spec(env_id).kwargs or {}).get("density", 1)
    expected = observation_space(1, {**default_config(), "density": density, **config, "n_avs": 1}).shape[1:]
    space = model.observation_space
    local = space[LOCAL_KEY] if isinstance(space, spaces.Dict) else space
    if local.shape != expected:
        raise ValueError(
            f"{path} observes {local.shape} per AV, but {env_id} with this run's scenario config shows each AV "
            f"{expected} (vehicles × features): the model was trained on another observation."
        )


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

    def load_model(self, device: str = "auto", trust_remote_code: bool = False) -> BaseAlgorithm:
        """The run's model, loaded without unpickling anything (unless ``trust_remote_code``,
        :mod:`sb3_marl.algos.common.loading`); a ValueError naming the file if it is not a readable model of ``algo``."""
        check_model_file(self.model_path, self.algo, trust_remote_code)
        try:
            model = get_algo(self.algo).load(self.model_path, device=device, trust_remote_code=trust_remote_code)
        except UnsafeModelError:
            raise
        except Exception as error:  # a truncated zip, tensors that do not fit the policy, ...
            raise ValueError(
                f"{self.model_path} is not a readable {self.algo} model ({type(error).__name__}: {error})."
            ) from None
        check_observation_shape(model, self.model_path, self.env_id, self.env_config)
        return model

    def evaluate(
        self,
        model: BaseAlgorithm,
        n_episodes: int,
        seed: int,
        deterministic: bool = False,
        progress: bool = False,
        traffic: bool = False,
    ) -> dict[str, Any]:
        """The paper's metrics of ``model`` on ``n_episodes`` seeded episodes of the run's scenario,
        with the safety supervisor (top level, the authors' protocol) and without it
        (``supervisor_off``), with what identifies the evaluation (algo, env, timesteps, seeds, env
        config and the supervisor version it ran, protocol: sampled actions by default, the authors')
        and each return; with ``traffic``, the
        traffic metrics and trip records (:func:`~sb3_marl.evaluation.evaluate_protocols`)."""
        return {
            "algo": self.algo,
            "env_id": self.env_id,
            "num_timesteps": int(model.num_timesteps),
            "deterministic": deterministic,
            "protocol": protocol_label(deterministic, uses_action_masks(model)),
            "seeds": [seed, seed + n_episodes - 1],
            "env_config": self.env_config,
            "supervisor_version": supervisor_version(self.env_config, scenario_of(self.env_id)),
            **evaluate_protocols(
                model_policy(model, deterministic), self.env_id, n_episodes, seed, self.env_config, progress, traffic
            ),
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

    def model_of(run: int) -> tuple[str, str]:
        try:
            _, model_path, log_path = get_model_path(
                run,
                str(folder),
                algo,
                env_name,
                load_best,
                None if load_checkpoint is None else str(load_checkpoint),
                load_last_checkpoint,
            )
        except (AssertionError, ValueError) as error:
            raise FileNotFoundError(str(error)) from None
        return model_path, log_path

    if exp_id == 0:  # the latest run that has the model asked for (a run that crashed early may have none)
        runs = [run_id(path) for path in run_folders(folder, algo, env_id)]
        if not runs:
            raise FileNotFoundError(f"No run of {algo} on {env_id} in {algo_folder}/ (expected {env_name}_<id>/ folders).")
        for run in reversed(runs):
            try:
                model_path, log_path = model_of(run)
                break
            except FileNotFoundError as error:
                missing = error
        else:
            raise FileNotFoundError(f"None of the runs {runs} of {algo} on {env_id} has the model asked for: {missing}")
    else:
        model_path, log_path = model_of(exp_id)
    return Run(algo, env_id, Path(log_path), inside(model_path, log_path), run_hyperparams(algo, env_id, log_path))


def run_hyperparams(algo: str, env_id: str, log_path: str | Path) -> dict[str, Any]:
    """The hyperparameters a run was trained with: its ``<env name>/config.yml``, read as plain data
    from inside the run (not through a link out of it) and checked as ``train`` checks them (every
    key one a run writes); {} without the file.

    :raises ValueError: naming the file and the bad key or value
    """
    config_path = Path(log_path) / str(EnvironmentName(env_id)) / "config.yml"
    if not config_path.is_file():
        return {}
    hyperparams = read_run_yaml(inside(config_path, log_path))
    try:
        validate_hyperparams(algo, hyperparams, env_id)
    except ValueError as error:
        raise ValueError(f"{config_path}: {error}") from None
    return hyperparams


def latest_checkpoint(run_folder: str | Path) -> Path | None:
    """The run's checkpoint ``rl_model_<steps>_steps.zip`` with the most steps (None without one);
    checkpoints are written atomically, so each one present is complete."""
    checkpoints = list(Path(run_folder).glob("rl_model_*_steps.zip"))
    steps = {path: int(path.stem.split("_")[2]) for path in checkpoints if path.stem.split("_")[2].isdigit()}
    return max(steps, key=steps.__getitem__) if steps else None


def run_id(run_folder: str | Path) -> int:
    """The id of a run folder ``<env name>_<id>`` (rl-zoo's layout)."""
    name = Path(run_folder).name
    prefix, _, number = name.rpartition("_")
    if not prefix or not number.isdigit():
        raise ValueError(f"{run_folder} is not a run folder <env name>_<id>.")
    return int(number)


def run_folders(folder: str | Path, algo: str, env_id: str) -> list[Path]:
    """All run folders of ``algo`` on ``env_id`` under ``folder``, by run id."""
    prefix = f"{EnvironmentName(env_id)}_"
    algo_folder = Path(folder) / algo
    if not algo_folder.is_dir():
        return []
    runs = [p for p in algo_folder.iterdir() if p.is_dir() and p.name.startswith(prefix) and p.name[len(prefix) :].isdigit()]
    return sorted(runs, key=run_id)


def run_args(run_folder: str | Path, env_id: str) -> dict[str, Any]:
    """The command-line arguments a run was trained with (its ``<env>/args.yml``; {} if absent)."""
    path = Path(run_folder) / str(EnvironmentName(env_id)) / "args.yml"
    return read_run_yaml(path) if path.is_file() else {}


def run_conf_name(run_folder: str | Path, env_id: str) -> str:
    """The name of the zoo config a run was trained with instead of its learner's (``-conf``), e.g.
    ``ma2c_safe``; "" for the learner's own."""
    conf_file = run_args(run_folder, env_id).get("conf_file")
    return Path(str(conf_file)).stem if conf_file else ""


def run_overrides(run_folder: str | Path, env_id: str) -> str:
    """What a run was trained with beyond its learner's zoo config: the ``-conf`` file's name and
    the ``-params`` overrides, as ``ma2c_safe, key=value, ...`` ("" if none)."""
    overrides = run_args(run_folder, env_id).get("hyperparams") or {}
    conf = [name] if (name := run_conf_name(run_folder, env_id)) else []
    return ", ".join([*conf, *(f"{key}={value}" for key, value in sorted(overrides.items()))])


def summary_table(folder: str | Path) -> str:
    """A markdown table of every evaluated run under ``folder`` (rl-zoo layout: each run folder's
    ``evaluation.json``, written by ``sb3-marl evaluate``; ``trained-agents/`` left out): algorithm, env, run, seed, the
    ``-params`` overrides it was trained with, and the evaluation (protocol, episodes, metrics, and the
    reference policies' rows where it was evaluated ``--with-baselines``); the merge's columns
    too where every row has them (as :func:`~sb3_marl.evaluation.markdown_table`)."""
    from sb3_marl.evaluation import MERGE_COLUMNS, TABLE_COLUMNS

    titles = [
        "algo",
        "env",
        "run",
        "seed",
        "overrides",
        "timesteps",
        "protocol",
        "supervisor",
        "episodes",
        *(title for title, _ in TABLE_COLUMNS),
    ]
    rows: list[tuple[list[str], list[str] | None]] = []
    evaluations = [path for path in Path(folder).glob("*/*/evaluation.json") if path.parent.parent.name in ALGO_NAMES]
    for evaluation_file in sorted(
        evaluations, key=lambda p: (p.parent.parent.name, p.parent.name.rpartition("_")[0], run_id(p.parent))
    ):
        try:
            rows += _summary_rows(evaluation_file, read_json_object(evaluation_file))
        except (KeyError, TypeError, AttributeError) as error:  # an edited evaluation.json
            raise ValueError(f"{evaluation_file} is not an evaluation written by `sb3-marl evaluate` ({error!r}).") from None
    merge = bool(rows) and all(merge_cells is not None for _, merge_cells in rows)
    titles += [title for title, _ in MERGE_COLUMNS] if merge else []
    lines = ["| " + " | ".join(titles) + " |", "|" + "---|" * len(titles)]
    lines += ["| " + " | ".join([*cells, *((merge and merge_cells) or [])]) + " |" for cells, merge_cells in rows]
    return "\n".join(lines)


def _summary_rows(evaluation_file: Path, result: dict[str, Any]) -> list[tuple[list[str], list[str] | None]]:
    """The summary table's rows of one run's ``evaluation.json`` (``result``): each row's cells, and
    its merge columns' cells (None off the merge)."""
    from sb3_marl.evaluation import MERGE_COLUMNS, TABLE_COLUMNS

    run_folder = evaluation_file.parent
    args = run_args(run_folder, result["env_id"])
    label = [
        result["algo"],
        result["env_id"],
        str(run_id(run_folder)),
        str(args.get("seed", "-")),
        run_overrides(run_folder, result["env_id"]) or "-",
    ]
    rows = [(label, result["num_timesteps"], result.get("protocol", "-"), result)]
    for name, baseline in (result.get("baselines") or {}).items():
        rows.append(([name, result["env_id"], "-", "-", "-"], "-", "reference policy", baseline))
    lines = []
    for cells, timesteps, protocol, summary in rows:
        for supervisor, metrics in (("on", summary), ("off", summary.get("supervisor_off"))):
            if metrics is None:  # an evaluation from before both protocols existed
                continue
            episodes = str(metrics.get("episodes", "-"))
            values = [*cells, str(timesteps), protocol, supervisor, episodes, *(fmt(metrics) for _, fmt in TABLE_COLUMNS)]
            lines.append((values, [fmt(metrics) for _, fmt in MERGE_COLUMNS] if "merge_rate" in metrics else None))
    return lines


def check_model_file(path: str | Path, algo: str, trust_remote_code: bool = False) -> None:
    """``path`` must be a readable SB3 model zip saved by ``algo``'s class: a ValueError naming the
    file otherwise (corrupt or truncated zip, another algorithm's model)."""
    expected = get_algo(algo)
    data = read_model_data(path)  # the readable JSON only: nothing is unpickled
    saved = data.get("algorithm_class")
    if saved is not None and saved != expected.__name__:
        raise ValueError(f"{path} is a {saved} model, not a {algo} ({expected.__name__}) model.")
    if not trust_remote_code and saved_policy_class(data, expected) is None:
        entry = data.get("policy_class") or {}
        raise ValueError(
            f"{path}: its entry 'policy_class' is not a policy {algo} ({expected.__name__}) uses (module "
            f"{entry.get('__module__', 'unknown')}; expected one of "
            f"{sorted(p.__name__ for p in expected.policy_aliases.values())}). A model of another tool that you "
            "trust loads with trust_remote_code=True (command line: --trust-remote-code)."
        )


__all__ = [
    "Run",
    "RunSpec",
    "check_model_file",
    "find_run",
    "latest_checkpoint",
    "run_args",
    "run_conf_name",
    "run_folders",
    "run_id",
    "run_overrides",
    "summary_table",
]
