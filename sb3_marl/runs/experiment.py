"""rl_zoo3's ExperimentManager, taught to train on the multi-agent scenario.

rl_zoo3 keeps doing what it does: log folders ``<log_folder>/<algo>/<env>_<run>/``, ``config.yml``
and ``args.yml``, ``-params`` overrides, schedules, progress bar, continuing from ``-i``, saving
the final model. This subclass changes only what a multi-agent VecEnv needs:

- hyperparameters come from ``zoo_configs/<algo>.yml`` and are validated (unknown keys, policy,
  architecture) before anything is created; the scenario keys (``reward_mode``, ``n_copies``,
  ``env_config``, ``reward_scale``, ``architecture``) configure the env and the MA2C network;
- the env is a :class:`~wrappers.ParameterSharingVecEnv` (rl_zoo3's ``n_envs`` = AV slots);
- evaluation scores the paper's metric (:class:`~sb3_marl.runs.callbacks.ScenarioEvalCallback`),
  driving metrics go to TensorBoard, checkpoints and the final model are written atomically;
- ``-i`` continues the timestep count of the loaded model up to ``n_timesteps`` in total.
"""

from __future__ import annotations

import os
import sys
from collections import OrderedDict
from typing import Any

import optuna
import rl_zoo3.utils as zoo_utils
from rl_zoo3.exp_manager import ExperimentManager
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback, ProgressBarCallback
from stable_baselines3.common.logger import HumanOutputFormat, KVWriter, Logger, make_output_format
from stable_baselines3.common.vec_env import VecEnv

from sb3_marl.algos import ALGOS
from sb3_marl.algos.common.policies import unchecked_distributions
from sb3_marl.common.files import REPLAY_BUFFER_FILE, read_replay_buffer, write_replay_buffer
from sb3_marl.envs import copy_av_counts
from sb3_marl.runs.callbacks import (
    AtomicCheckpointCallback,
    DrivingMetricsCallback,
    FiniteWeightsCallback,
    ProgressLinesCallback,
    ScenarioEvalCallback,
    StoreExecutedActions,
    atomic_save,
)
from sb3_marl.runs.folders import RunSpec, run_id
from sb3_marl.runs.hyperparams import (
    SCENARIO_KEYS,
    config_file,
    load_hyperparams,
    merge_hyperparams,
    parse_string_values,
    policy_for,
    policy_kwargs_for,
    validate_hyperparams,
)
from sb3_marl.runs.training import make_venv
from sb3_marl.runs.tuning import SAMPLERS, TrialPruningCallback, best_hyperparams_yaml, config_trial, merge_sampled

# rl_zoo3 builds and loads models through its ALGOS table: our learners join it once, under their
# own names (no clash with rl_zoo3's a2c, ppo, ...)
zoo_utils.ALGOS.update(ALGOS)

#: Evaluation episodes use seeds from ``seed + EVAL_SEED_OFFSET`` on, apart from training seeds.
EVAL_SEED_OFFSET = 10_000


def interrupted_by_user(error: BaseException | None) -> bool:
    """Whether ``error`` is, or was caused by, a KeyboardInterrupt (Ctrl-C, or SIGTERM as the CLI
    maps it). A signal that arrives while compiled (numba) code is running raises its
    KeyboardInterrupt inside numba's dispatcher, which reports it as a SystemError caused by it."""
    seen = set()
    while error is not None and id(error) not in seen:
        if isinstance(error, KeyboardInterrupt):
            return True
        seen.add(id(error))
        error = error.__cause__ or error.__context__
    return False


class MARLExperimentManager(ExperimentManager):
    """:class:`rl_zoo3.exp_manager.ExperimentManager` on a ParameterSharingVecEnv (see module doc),
    for the run ``spec``.

    :param callback_after_eval: called after each evaluation, as SB3's ``EvalCallback(callback_after_eval=...)``
    """

    def __init__(self, spec: RunSpec, callback_after_eval: BaseCallback | None = None) -> None:
        super().__init__(
            spec,  # type: ignore[arg-type]  # rl_zoo3 only saves vars(args) as args.yml
            spec.algo,
            spec.env,
            spec.log_folder,
            config=spec.conf_file or str(config_file(spec.algo)),
            vec_env_type="dummy",
            tensorboard_log=spec.tensorboard_folder,
            n_timesteps=spec.n_timesteps,
            eval_freq=spec.eval_freq,
            n_eval_episodes=spec.eval_episodes,
            save_freq=spec.save_freq,
            hyperparams=spec.hyperparams,
            trained_agent=spec.trained_agent,
            seed=spec.seed,
            log_interval=spec.log_interval,
            verbose=spec.verbose,
            device=spec.device,
            show_progress=spec.progress,
            optimize_hyperparameters=spec.optimize_hyperparameters,
            n_trials=spec.n_trials,
            n_jobs=spec.n_jobs,
            sampler=spec.sampler,
            pruner=spec.pruner,
            n_startup_trials=spec.n_startup_trials,
            n_evaluations=spec.n_evaluations,  # type: ignore[arg-type]  # None: hyperparameters_optimization's default
            storage=spec.storage,
            study_name=spec.study_name,
        )
        self.spec = spec
        self.cli_overrides = {
            key: value for key, value in (("n_copies", spec.n_envs), ("reward_mode", spec.reward_mode)) if value is not None
        }
        if spec.run_id is not None:
            self.save_path = os.path.join(self.log_path, f"{self.env_name}_{spec.run_id}")
            self.params_path = os.path.join(self.save_path, str(self.env_name))
        self.callback_after_eval = callback_after_eval
        self.scenario: dict[str, Any] = {}
        self.interrupted = False
        self.best_config_path: str | None = None  # written by hyperparameters_optimization

    # ---- hyperparameters ----------------------------------------------------------------------

    def read_hyperparameters(self) -> tuple[dict[str, Any], dict[str, Any]]:
        hyperparams = load_hyperparams(self.algo, self.env_name.gym_id, path=self.config)
        hyperparams = parse_string_values(merge_hyperparams(hyperparams, self.custom_hyperparams))
        hyperparams.update(self.cli_overrides)
        validate_hyperparams(self.algo, hyperparams, self.env_name.gym_id)
        self.config_hyperparams = dict(hyperparams)
        saved_hyperparams = OrderedDict((key, hyperparams[key]) for key in sorted(hyperparams))
        if self.verbose > 0:
            print(f"Hyperparameters for {self.algo} on {self.env_name.gym_id} (from {self.config}):")
            for key, value in saved_hyperparams.items():
                print(f"  {key}: {value}")
        return hyperparams, saved_hyperparams

    def _preprocess_hyperparams(self, hyperparams: dict[str, Any]) -> tuple:
        self.scenario = {key: hyperparams.pop(key) for key in SCENARIO_KEYS if key in hyperparams}
        verbose, self.verbose = self.verbose, 0  # rl_zoo3 would print "Using 1 environments": ours below
        try:
            hyperparams, env_wrapper, callbacks, vec_env_wrapper = super()._preprocess_hyperparams(hyperparams)
        finally:
            self.verbose = verbose
        hyperparams["policy_kwargs"] = policy_kwargs_for(self.algo, {**hyperparams, **self.scenario})
        hyperparams["policy"] = policy_for({**hyperparams, **self.scenario})
        # rl_zoo3 divides eval/save frequencies by n_envs: every VecEnv step is one step per AV slot
        counts = copy_av_counts(self.env_name.gym_id, self.scenario.get("env_config"), self.scenario.get("n_copies"))
        self.n_envs = sum(counts)
        if self.verbose > 0:
            print(
                f"{len(counts)} scenario copies with {', '.join(map(str, counts))} AVs: {self.n_envs} AV slots "
                "of one VecEnv, one shared policy"
            )
        return hyperparams, env_wrapper, callbacks, vec_env_wrapper

    # ---- env, callbacks, model ----------------------------------------------------------------

    def _load_pretrained_agent(self, hyperparams: dict[str, Any], env: VecEnv) -> BaseAlgorithm:
        """rl_zoo3's continue-training load (``-i``), through the safe loader; the replay buffer
        beside the zip: ``replay_buffer.npz`` as data, ``replay_buffer.pkl`` (a pickle) only with
        ``trust_remote_code``."""
        print("Loading pretrained agent")
        hyperparams = {key: value for key, value in hyperparams.items() if key not in ("policy", "policy_kwargs")}
        model = ALGOS[self.algo].load(
            self.trained_agent,
            env=env,
            seed=self.seed,
            tensorboard_log=self.tensorboard_log,
            verbose=self.verbose,
            device=self.device,
            trust_remote_code=self.spec.trust_remote_code,
            **hyperparams,
        )
        folder = os.path.dirname(self.trained_agent)
        arrays, replay_buffer = os.path.join(folder, REPLAY_BUFFER_FILE), os.path.join(folder, "replay_buffer.pkl")
        if os.path.exists(arrays) and getattr(model, "replay_buffer", None) is not None:
            read_replay_buffer(model.replay_buffer, arrays)
        elif os.path.exists(replay_buffer) and hasattr(model, "load_replay_buffer"):
            if self.spec.trust_remote_code:
                model.load_replay_buffer(replay_buffer)
            else:
                print(
                    f"Not loading {replay_buffer}: a replay buffer is a pickle, which can run code; training "
                    "continues with an empty buffer (pass --trust-remote-code to load it)."
                )
        return model

    def create_log_folder(self) -> None:
        """The run folder, created exclusively: when another run took this id since it was chosen
        (two ``train`` started together), the next free id (a given ``run_id`` is continued)."""
        if self.optimize_hyperparameters:  # a search writes its report, not a run folder
            return
        if self.spec.run_id is None:
            os.makedirs(self.log_path, exist_ok=True)
            while True:
                try:
                    os.mkdir(self.save_path)
                    break
                except FileExistsError:
                    self.save_path = os.path.join(self.log_path, f"{self.env_name}_{run_id(self.save_path) + 1}")
            self.params_path = os.path.join(self.save_path, str(self.env_name))
        super().create_log_folder()

    def create_envs(self, n_envs: int, eval_env: bool = False, no_log: bool = False) -> VecEnv:
        monitor_dir = None if eval_env or no_log or self.optimize_hyperparameters else self.save_path
        return make_venv(
            self.env_name.gym_id,
            self.scenario,
            self.seed,
            self.spec.vec_env,
            monitor_dir=monitor_dir,
            monitor_file=self.spec.monitor_file,
        )

    def create_callbacks(self) -> None:
        if self.show_progress:  # a bar on a terminal, lines in a file
            self.callbacks.append(ProgressBarCallback() if sys.stdout.isatty() else ProgressLinesCallback())
        self.callbacks += [FiniteWeightsCallback(), DrivingMetricsCallback()]
        self.callbacks += self._stored_action_callbacks()
        if self.save_freq > 0:
            self.callbacks.append(
                AtomicCheckpointCallback(max(self.save_freq // self.n_envs, 1), self.save_path, "rl_model", verbose=1)
            )
        if self.eval_freq > 0:
            self.callbacks.append(
                ScenarioEvalCallback(
                    self.env_name.gym_id,
                    eval_freq=max(self.eval_freq // self.n_envs, 1),
                    n_eval_episodes=self.n_eval_episodes,
                    seed=self.seed + EVAL_SEED_OFFSET,
                    config=self.scenario.get("env_config"),
                    log_path=self.save_path,
                    best_model_save_path=self.save_path,
                    callback_after_eval=self.callback_after_eval,
                    evaluate_at_end=self.spec.evaluate_at_end,
                    verbose=self.verbose,
                )
            )

    def learn(self, model: BaseAlgorithm) -> None:
        """Train to ``n_timesteps`` in total (resumed runs continue their count); Ctrl-C or SIGTERM
        stops training cleanly so that the model can be saved."""
        remaining = self.n_timesteps - model.num_timesteps if self.continue_training else self.n_timesteps
        # TensorBoard run <ALGO>_<id> matches the log folder <env>_<id>, resumed runs included
        # SB3's logger tables on the console with --verbose 2 (1: progress and evaluation lines)
        outputs: list[KVWriter] = [HumanOutputFormat(sys.stdout)] if self.verbose >= 2 else []
        tensorboard_folder = None
        if self.tensorboard_log:
            tensorboard_folder = os.path.join(self.tensorboard_log, f"{self.algo.upper()}_{self.run_id}")
            outputs.append(make_output_format("tensorboard", tensorboard_folder))
        model.set_logger(Logger(tensorboard_folder, outputs))
        kwargs: dict[str, Any] = {"callback": self.callbacks}
        if self.log_interval > -1:
            kwargs["log_interval"] = self.log_interval
        try:
            if remaining > 0:
                with unchecked_distributions():
                    model.learn(remaining, reset_num_timesteps=not self.continue_training, **kwargs)
            else:
                print(f"The loaded model has {model.num_timesteps} timesteps >= n_timesteps={self.n_timesteps}.")
        except BaseException as error:  # Ctrl-C / SIGTERM: stop, keep what was learnt
            if not interrupted_by_user(error):
                raise
            self.interrupted = True
        finally:
            if self.callbacks:
                self.callbacks[0].on_training_end()
            model.logger.close()  # flushes the TensorBoard events
            assert model.env is not None
            model.env.close()

    def _stored_action_callbacks(self) -> list[BaseCallback]:
        """``stored_actions: executed`` stores the supervisor's action in the rollout (a callback)."""
        return [StoreExecutedActions()] if self.scenario.get("stored_actions") == "executed" else []

    # ---- hyperparameter search (-optimize) ----------------------------------------------------

    def objective(self, trial: optuna.Trial) -> float:
        """One Optuna trial: train with sampled hyperparameters on the scenario and score the mean
        return of the last evaluation (the paper's metric), reporting each one for pruning."""
        sampled = SAMPLERS[self.algo][0](
            trial, self.n_actions, self.n_envs, {"using_her_replay_buffer": False, "her_kwargs": {}}
        )
        kwargs = merge_sampled(self._hyperparams, sampled)
        env = self.create_envs(self.n_envs, no_log=True)
        # every trial starts from the same seed, so that trials differ only in their hyperparameters
        model = ALGOS[self.algo](env=env, seed=self.seed, verbose=0, device=self.device, **kwargs)
        pruning = TrialPruningCallback(trial)
        evaluation = ScenarioEvalCallback(
            self.env_name.gym_id,
            eval_freq=max(self.n_timesteps // self.n_evaluations // self.n_envs, 1),
            n_eval_episodes=self.n_eval_episodes,
            seed=self.seed + EVAL_SEED_OFFSET,
            config=self.scenario.get("env_config"),
            callback_after_eval=pruning,
            evaluate_at_end=True,
            verbose=0,
        )
        try:
            with unchecked_distributions():
                model.learn(self.n_timesteps, callback=[evaluation, *self._stored_action_callbacks()])
        except (AssertionError, ValueError) as error:  # NaNs from extreme hyperparameters: rl-zoo prunes
            print(f"Trial {trial.number} failed ({error}); pruned. Sampled: {sampled}")
            raise optuna.exceptions.TrialPruned() from error
        finally:
            env.close()
        if pruning.is_pruned:
            raise optuna.exceptions.TrialPruned()
        return evaluation.last_summary["return_mean"]

    def hyperparameters_optimization(self) -> None:
        """Optuna search with rl_zoo3's sampler and pruner (``--sampler``, ``--pruner``), in
        ``--storage`` (a database URL or a ``.log`` journal file; a study of the same
        ``--study-name`` there is continued) or in memory. The sampler is seeded with ``--seed``
        plus the number of trials already in the study, so that a resumed study or a second worker
        on the same storage (started after the first has begun a trial) does not repeat its draws.
        Writes the trials to ``<log_folder>/<algo>/report_<env>_<study>.csv`` and the best one as a
        zoo-config entry to ``best_<env>_<study>.yml`` beside it."""
        storage: Any = self.storage
        if storage is not None and storage.endswith(".log"):
            os.makedirs(os.path.dirname(os.path.abspath(storage)), exist_ok=True)
            storage = optuna.storages.JournalStorage(optuna.storages.journal.JournalFileBackend(storage))  # type: ignore[attr-defined]
        study = optuna.create_study(
            sampler=self._create_sampler(self.sampler),
            pruner=self._create_pruner(self.pruner),
            storage=storage,
            study_name=self.study_name,
            load_if_exists=True,
            direction="maximize",
        )
        done = len(study.trials)
        if done:  # a resumed study, or a second worker on the same storage: not the same draws again
            seed, self.seed = self.seed, self.seed + done
            study.sampler = self._create_sampler(self.sampler)
            self.seed = seed
        shipped = config_trial(self.algo, self.config_hyperparams)
        if done == 0 and shipped is not None:
            study.enqueue_trial(shipped, user_attrs={"shipped_config": True})
            print(f"Trial 0 is the configuration as shipped: {shipped}")
        print(
            f"Study {study.study_name!r}: {done} earlier trial(s); running {self.n_trials} more "
            f"(sampler {self.sampler}, pruner {self.pruner}, {self.n_evaluations} evaluation(s) per trial)"
        )
        try:
            study.optimize(self.objective, n_trials=self.n_trials, n_jobs=self.n_jobs, gc_after_trial=True)
        except BaseException as error:
            if not interrupted_by_user(error):
                raise
            self.interrupted = True
        folder = os.path.join(self.log_folder, self.algo)
        os.makedirs(folder, exist_ok=True)
        stem = os.path.join(folder, f"{{}}_{self.env_name}_{study.study_name}")
        study.trials_dataframe().to_csv(stem.format("report") + ".csv")
        complete = study.get_trials(deepcopy=False, states=[optuna.trial.TrialState.COMPLETE])
        pruned = study.get_trials(deepcopy=False, states=[optuna.trial.TrialState.PRUNED])
        print(
            f"Trials: {len(study.trials)} ({len(complete)} complete, {len(pruned)} pruned); "
            f"report: {stem.format('report')}.csv"
        )
        self.best_config_path = None
        if not complete:
            print("No trial completed: no best hyperparameters to write.")
            return
        best = study.best_trial
        self.best_config_path = stem.format("best") + ".yml"
        with open(self.best_config_path, "w") as file:
            file.write(
                best_hyperparams_yaml(
                    self.algo, self.env_name.gym_id, self.config_hyperparams, best.params, float(best.value or 0.0)
                )
            )
        print(f"Best trial {best.number}: mean evaluation return {best.value:.2f}")
        for key, value in best.params.items():
            print(f"    {key}: {value}")
        first = study.trials[0]
        if first.user_attrs.get("shipped_config") and first.state == optuna.trial.TrialState.COMPLETE:
            print(f"The configuration as shipped (trial 0): {first.value:.2f}")
        print(f"Its hyperparameters as a zoo-config entry: {self.best_config_path}")

    @property
    def run_id(self) -> int:
        """The run's id: ``<env>_<id>`` of its log folder."""
        return run_id(self.save_path)

    def save_trained_model(self, model: BaseAlgorithm) -> None:
        path = atomic_save(model, os.path.join(self.save_path, f"{self.env_name}.zip"))
        print(f"Saved the model ({model.num_timesteps} timesteps) to {path}")
        buffer = getattr(model, "replay_buffer", None)
        if self.spec.save_replay_buffer and buffer is not None:
            write_replay_buffer(buffer, os.path.join(self.save_path, REPLAY_BUFFER_FILE))


__all__ = ["EVAL_SEED_OFFSET", "MARLExperimentManager"]
