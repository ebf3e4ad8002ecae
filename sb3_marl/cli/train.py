"""``sb3-marl train``: rl-zoo's train.py flags (and its hyperparameter search, ``-optimize``)."""

from __future__ import annotations

import argparse
import os
import signal
import time
from pathlib import Path
from typing import Any

from sb3_marl.algos import ALGO_NAMES
from sb3_marl.cli.common import (
    DEFAULT_ENV,
    EXIT_INTERRUPTED,
    MAX_COPIES,
    MAX_COUNT,
    MAX_EPISODES,
    CommandFailed,
    StopOnSignals,
    StoreHyperparams,
    UsageError,
    add_num_threads,
    add_refused_flags,
    add_trust_remote_code,
    check_device,
    check_folder,
    check_seed,
    every,
    os_error_text,
    positive,
    positive_or_default,
    set_num_threads,
)
from sb3_marl.envs import MERGE_ENV_IDS, SCENARIO_IDS


def add_parsers(commands: Any) -> None:
    """Add train's subcommands to the ``sb3-marl`` parser's ``commands``."""
    train = commands.add_parser("train", help="train a learner (rl-zoo's train.py flags)")
    train.add_argument("--algo", default="ma2c", choices=ALGO_NAMES, help="learner (default: ma2c)")
    train.add_argument("--env", default=DEFAULT_ENV, choices=SCENARIO_IDS, help="scenario id")
    train.add_argument(
        "-n",
        "--n-timesteps",
        type=positive_or_default,
        default=-1,
        help="AV-steps to train (>= 1); -1: the config's n_timesteps",
    )
    train.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    train.add_argument("-f", "--log-folder", default="logs", help="log folder (default: logs)")
    train.add_argument(
        "-tb", "--tensorboard-log", default=None, help="TensorBoard folder (default: <log-folder>/tensorboard; '' disables)"
    )
    train.add_argument("--eval-freq", type=every, default=10_000, help="evaluate every N AV-steps; -1 disables")
    train.add_argument(
        "--eval-episodes", type=positive(maximum=MAX_EPISODES), default=5, help="episodes per evaluation (default: 5)"
    )
    train.add_argument("--save-freq", type=every, default=-1, help="checkpoint every N AV-steps; -1 disables")
    train.add_argument(
        "-c",
        "-conf",
        "--conf-file",
        default=None,
        help="YAML instead of zoo_configs/<algo>.yml, or a shipped zoo config's name (ma2c_safe: the safe recipe)",
    )
    train.add_argument(
        "-params",
        "--hyperparams",
        nargs="+",
        action=StoreHyperparams,
        default={},
        metavar="KEY:VALUE",
        help="override hyperparameters, e.g. n_steps:20 reward_mode:'global'",
    )
    train.add_argument(
        "--env-kwargs",
        nargs="+",
        action=StoreHyperparams,
        default={},
        metavar="KEY:VALUE",
        help="scenario config overrides (merged into env_config), e.g. safety_supervisor:False",
    )
    train.add_argument("-i", "--trained-agent", default="", help="continue training this model zip (counts on)")
    train.add_argument(
        "--save-replay-buffer",
        action="store_true",
        help="write an off-policy learner's replay buffer beside the final model (replay_buffer.npz)",
    )
    train.add_argument(
        "--vec-env", default="dummy", choices=["dummy", "subproc"], help="scenario copies in process or in workers"
    )
    train.add_argument(
        "--n-envs", type=positive(maximum=MAX_COPIES), default=None, help="scenario copies (default: the config's)"
    )
    train.add_argument(
        "--reward-mode", choices=["local", "global", "individual"], default=None, help="overrides the config's reward_mode"
    )
    train.add_argument(
        "-P", "--progress", action="store_true", help="progress bar (tqdm + rich); in a file or a pipe, a line per tenth"
    )
    train.add_argument("--device", default="auto", help="torch device (default: auto)")
    add_trust_remote_code(train)
    add_num_threads(train)
    train.add_argument(
        "--log-interval", type=positive_or_default, default=-1, help="SB3 log_interval (>= 1); -1: the algorithm's default"
    )
    train.add_argument(
        "--verbose",
        type=int,
        default=1,
        choices=[0, 1, 2],
        help="0: quiet; 1 (default): set-up, progress and evaluation lines; 2: also SB3's logger tables",
    )
    _add_search_flags(train.add_argument_group("hyperparameter search (rl-zoo's -optimize, Optuna)"))
    add_refused_flags(train, REFUSED_FLAGS)
    train.set_defaults(handler=train_command)


#: rl-zoo's train flags that have no meaning here -> why (refused with that message).
REFUSED_FLAGS = {
    ("-uuid", "--uuid"): "run folders are created exclusively (<env>_<id>, the next free id): two runs never share one",
    ("--gym-packages",): "the scenarios register themselves when sb3_marl is imported",
    ("--eval-env-kwargs",): "evaluation runs the training scenario with the supervisor on and off (--env-kwargs sets both)",
    ("--n-eval-envs",): "evaluation runs one scenario copy per AV count of the density, as training",
    ("--truncate-last-trajectory",): "training never stops mid-episode here: no HER replay buffer to truncate",
    ("--optimization-log-path", "--no-optim-plots", "--max-total-trials", "--trial-id"): (
        "-optimize keeps its study in --storage (resumed from there) and writes no per-trial logs"
    ),
    ("--track", "--wandb-project-name", "--wandb-entity", "--wandb-group", "-tags", "--wandb-tags"): (
        "Weights & Biases is not a dependency: TensorBoard logs are in <log-folder>/tensorboard "
        "(wandb sync <that folder> uploads them)"
    ),
}


def _add_search_flags(search: Any) -> None:
    """rl-zoo's ``-optimize`` flags, on the argument group ``search``."""
    search.add_argument(
        "-optimize",
        "--optimize-hyperparameters",
        action="store_true",
        help="search hyperparameters instead of training one model",
    )
    search.add_argument("--n-trials", type=positive(maximum=MAX_COUNT), default=500, help="trials to run (default: 500)")
    search.add_argument(
        "--n-jobs", type=positive(maximum=MAX_COPIES), default=1, help="trials in parallel (threads; default: 1)"
    )
    search.add_argument("--sampler", default="tpe", choices=["tpe", "random"], help="Optuna sampler (default: tpe)")
    search.add_argument(
        "--pruner", default="median", choices=["median", "halving", "none"], help="Optuna pruner (default: median)"
    )
    search.add_argument(
        "--n-startup-trials",
        type=int,
        default=10,
        help="trials before the TPE sampler and the median pruner act (default: 10)",
    )
    search.add_argument(
        "--n-evaluations",
        type=positive(),
        default=None,
        help="evaluations per trial, for pruning (default: one per 100k AV-steps)",
    )
    search.add_argument(
        "--storage", default=None, help="database URL (sqlite:///study.db) or .log journal file; a study is resumed from it"
    )
    search.add_argument("--study-name", default=None, help="study name in --storage (required with it)")


def _check_train_args(args: argparse.Namespace) -> None:
    """Everything about ``train``'s flags that can be checked before any work or folder."""
    from sb3_marl.algos import get_algo
    from sb3_marl.algos.common.loading import safe_custom_objects
    from sb3_marl.runs.folders import RunSpec, check_model_file
    from sb3_marl.runs.hyperparams import conf_file_path, is_q_learning

    check_seed(args.seed)
    if args.env_kwargs:  # rl-zoo's --env-kwargs: the scenario's config, merged key by key
        args.hyperparams = {
            **args.hyperparams,
            "env_config": {**(args.hyperparams.get("env_config") or {}), **args.env_kwargs},
        }
    if args.save_replay_buffer and not is_q_learning(args.algo):
        raise UsageError(f"--save-replay-buffer: {args.algo} learns on-policy and has no replay buffer (madqn has one).")
    check_folder("-f/--log-folder", args.log_folder)
    # the TensorBoard folder the run will use, the default one inside -f too (it may belong to another user)
    check_folder("-tb/--tensorboard-log", RunSpec.from_args(args).tensorboard_folder)
    check_device(args.device)
    if args.conf_file:
        try:
            args.conf_file = str(conf_file_path(args.conf_file))
        except ValueError as error:
            raise UsageError(f"-c/--conf-file: {error}") from None
    if args.optimize_hyperparameters:
        if args.trained_agent:
            raise UsageError("-optimize searches from scratch: it cannot continue -i/--trained-agent.")
        if args.n_startup_trials < 0:
            raise UsageError(f"--n-startup-trials: expected an integer >= 0, got {args.n_startup_trials}.")
        if args.storage is not None and not args.study_name:
            raise UsageError("--storage needs --study-name, so that a later invocation resumes the same study.")
        if args.storage is not None and not (args.storage.endswith(".log") or "://" in args.storage):
            raise UsageError(f"--storage: {args.storage!r} is neither a database URL (sqlite:///study.db) nor a .log file.")
    if args.trained_agent:
        if not (args.trained_agent.endswith(".zip") and os.path.isfile(args.trained_agent)):
            raise UsageError(f"-i/--trained-agent: {args.trained_agent!r} is not an existing .zip model file.")
        try:
            check_model_file(args.trained_agent, args.algo, args.trust_remote_code)
            if not args.trust_remote_code:
                safe_custom_objects(get_algo(args.algo), args.trained_agent)  # refused here, before any folder
            _check_trained_agent(args)
        except ValueError as error:
            raise UsageError(f"-i/--trained-agent: {error}") from None


def _check_trained_agent(args: argparse.Namespace) -> None:
    """The ``-i`` model loads (its tensors readable) and observes what ``--env`` with the run's
    hyperparameters shows each AV: a ValueError naming the file otherwise."""
    from sb3_marl.algos import get_algo
    from sb3_marl.algos.common.loading import UnsafeModelError
    from sb3_marl.common.files import read_run_yaml
    from sb3_marl.runs.folders import check_observation_shape
    from sb3_marl.runs.hyperparams import load_hyperparams, merge_hyperparams

    try:
        model = get_algo(args.algo).load(args.trained_agent, device="cpu", trust_remote_code=args.trust_remote_code)
    except UnsafeModelError:
        raise
    except Exception as error:  # a truncated zip, unreadable tensors, ...
        raise ValueError(
            f"{args.trained_agent} is not a readable {args.algo} model ({type(error).__name__}: {error})."
        ) from None
    try:
        hyperparams = merge_hyperparams(load_hyperparams(args.algo, args.env, args.conf_file), args.hyperparams)
    except ValueError:
        return  # bad hyperparameters: reported by their own check, with their own flag
    check_observation_shape(model, args.trained_agent, args.env, hyperparams.get("env_config") or {})
    shared = getattr(model.policy, "share_features_extractor", None)
    architecture = hyperparams.get("architecture", "default")
    if shared is not None and architecture in ("shared", "separate") and shared != (architecture == "shared"):
        actual = "shared" if shared else "separate"
        raise ValueError(
            f"{args.trained_agent} has the {actual} actor-critic network, the run's hyperparameters say "
            f"architecture: {architecture} (pass -params architecture:{actual})."
        )
    recorded = next(Path(args.trained_agent).parent.glob("*/args.yml"), None)  # the -i run's own arguments
    trained_on = read_run_yaml(recorded).get("env") if recorded else None
    if trained_on and trained_on != args.env:
        print(f"-i: the model was trained on {trained_on}; training continues on {args.env} (a curriculum).")


def train_command(args: argparse.Namespace) -> int:
    from sb3_marl.common.compiled import announce_compiling, compiling
    from sb3_marl.runs.callbacks import DivergedError
    from sb3_marl.runs.experiment import MARLExperimentManager
    from sb3_marl.runs.folders import RunSpec, latest_checkpoint

    _check_train_args(args)
    set_num_threads(args.num_threads)
    spec = RunSpec.from_args(args)
    tensorboard_log = spec.tensorboard_folder
    manager = MARLExperimentManager(spec)
    announce_compiling(merge=args.env in MERGE_ENV_IDS.values())
    try:
        experiment = manager.setup_experiment()
    except (ValueError, FileNotFoundError) as error:  # bad hyperparameters: nothing has been trained
        raise UsageError(str(error)) from None
    if args.optimize_hyperparameters:
        start = time.perf_counter()
        manager.hyperparameters_optimization()
        print(f"Search wall time: {time.perf_counter() - start:.1f} s")
        return EXIT_INTERRUPTED[signal.SIGINT] if manager.interrupted else 0
    model, _ = experiment  # type: ignore[misc]
    start = time.perf_counter()
    with StopOnSignals() as stop, compiling() as compile_time:
        try:
            manager.learn(model)
        except OSError as error:  # a full disk, a folder removed under us: saving would likely fail too
            raise CommandFailed(_write_failure(manager, model, error)) from None
        except DivergedError as error:  # NaN weights: nothing to keep from this point
            last = latest_checkpoint(manager.save_path)
            raise CommandFailed(
                f"{error}. Nothing was saved from it; "
                + (f"the last checkpoint is {last} (continue with -i {last})." if last else "no checkpoint was saved before.")
            ) from None
        except Exception as error:  # a dead worker, ...: keep what was learnt, then report
            try:
                manager.save_trained_model(model)
            except OSError as save_error:
                raise CommandFailed(
                    f"training stopped by {type(error).__name__}: {error}\n" + _write_failure(manager, model, save_error)
                ) from None
            cause = error.__cause__  # a worker's own traceback (see wrappers.copies.WorkerCopies)
            worker = f"\n{cause}" if isinstance(cause, RuntimeError) and str(cause).startswith("in the worker") else ""
            raise CommandFailed(
                f"training stopped by {type(error).__name__}: {error}{worker}\n"
                f"The model at {model.num_timesteps} timesteps was saved; continue with "
                f"-i {manager.save_path}/{manager.env_name}.zip"
            ) from error
    try:
        manager.save_trained_model(model)
    except OSError as error:
        raise CommandFailed(_write_failure(manager, model, error)) from None
    compiled = (
        f" ({compile_time.seconds:.1f} s of it compiling the road kernel, first run only)" if compile_time.seconds >= 1 else ""
    )
    print(f"Training wall time: {time.perf_counter() - start:.1f} s{compiled}, {model.num_timesteps} timesteps (AV-steps)")
    if tensorboard_log:
        print(f"TensorBoard: tensorboard --logdir {tensorboard_log}")
    if manager.interrupted:
        signum = stop.signal or signal.SIGINT
        print(
            f"Training interrupted ({signal.Signals(signum).name}); resume with -i {manager.save_path}/{manager.env_name}.zip"
        )
        return EXIT_INTERRUPTED[signal.Signals(signum)]
    return 0


def _write_failure(manager: Any, model: Any, error: OSError) -> str:
    """One message for a file training could not write (e.g. a full disk): what, and how to resume."""
    from sb3_marl.runs.folders import latest_checkpoint

    checkpoint = latest_checkpoint(manager.save_path)
    best = Path(manager.save_path) / "best_model.zip"
    resume = (
        f"The last complete checkpoint is {checkpoint}: continue with -i {checkpoint}."
        if checkpoint
        else "No checkpoint was written (--save-freq saves them)"
        + (f"; the best model so far is {best}." if best.is_file() else ".")
    )
    return (
        f"could not write at {model.num_timesteps} timesteps: {os_error_text(error)}. "
        f"The model of this moment could not be saved. {resume}"
    )
