"""The ``sb3-marl`` command line (also ``python -m sb3_marl``), with rl-zoo's flag names.

    sb3-marl train --algo ma2c --env sb3_marl/LaneChange-density1-v0 -n 100000 -f logs
    sb3-marl evaluate --algo ma2c --env sb3_marl/LaneChange-density1-v0 -f logs   (alias: enjoy)
    sb3-marl plot --algo ma2c mappo --env sb3_marl/LaneChange-density1-v0 -f logs
    sb3-marl record-video --algo ma2c --env sb3_marl/LaneChange-density1-v0 -f logs
    sb3-marl push-to-hub --algo ma2c --env sb3_marl/LaneChange-density1-v0 -f logs -orga ORG [--dry-run PATH]
    sb3-marl load-from-hub --repo-id ORG/NAME -f logs
    sb3-marl baselines --density 1        (reference policies: random, cruise and IDM/MOBIL)
    sb3-marl summary -f logs              (markdown table of the evaluated runs)
    sb3-marl benchmark --grid paper --budget 0.05   (the paper's experiments as Ray Tune trials)
    sb3-marl benchmark status -f logs/benchmark     (where each trial stands)
    sb3-marl benchmark report -f logs/benchmark -o results

Timesteps (``-n``, ``--eval-freq``, ``--save-freq``) count AV-steps, SB3's timesteps on the
parameter-sharing VecEnv: one step of a scenario copy with N AVs is N timesteps.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from sb3_marl import __version__
from sb3_marl.algos import ALGO_NAMES
from sb3_marl.benchmark.grid import (
    GRIDS,
    PAPER_EVAL_EPISODES,
    PAPER_EVAL_EVERY_EPISODES,
    PAPER_SEEDS,
)
from sb3_marl.envs import DENSITIES, ENV_IDS, make_scenario
from sb3_marl.files import write_text

DEFAULT_ENV = ENV_IDS[1]
EXIT_INTERRUPTED = {signal.SIGINT: 130, signal.SIGTERM: 143}


class StoreHyperparams(argparse.Action):
    """rl-zoo's ``-params key:value ...``: each value is a literal, never evaluated as code
    (:func:`sb3_marl.loading.parse_literal`: ``n_steps:20``, ``env_config:"dict(comfort=False)"``,
    ``policy_kwargs:"dict(activation_fn=nn.Tanh)"``); a bare word stays a string
    (``reward_mode:global``); anything else (a call, an operator) exits 2 naming the key."""

    def __call__(
        self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any, option_string: Any = None
    ) -> None:
        from sb3_marl.loading import parse_literal

        parsed = {}
        for item in values:
            key, sep, expression = item.partition(":")
            if not sep or not key:
                parser.error(f"argument {option_string}: expected key:value, got {item!r}")
            try:
                parsed[key] = parse_literal(expression, key)
            except ValueError as error:
                parser.error(f"argument {option_string}: {error}")
        setattr(namespace, self.dest, parsed)


#: Upper bounds of the sizes that allocate: scenario copies (each an env), episodes, seeds, trials.
MAX_COPIES, MAX_EPISODES, MAX_COUNT = 256, 100_000, 10_000


def _positive(kind: type = int, maximum: float | None = None) -> Any:
    def parse(text: str) -> Any:
        value = kind(text)
        if value < 1 or (maximum is not None and value > maximum):
            bound = "" if maximum is None else f" and <= {maximum:,}"
            raise argparse.ArgumentTypeError(f"expected a value >= 1{bound}, got {text}")
        return value

    return parse


def _positive_or_minus_one(expected: str) -> Any:
    """A parser of an integer >= 1, or -1 with rl-zoo's meaning (``expected`` says which); 0 and
    other values are refused with ``expected`` in the message."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = 0
        if value != -1 and value < 1:
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}")
        return value

    return parse


#: A period in AV-steps (0 is refused rather than silently meaning never), and a count or the default.
_every = _positive_or_minus_one("an integer >= 1 (AV-steps) or -1 (never)")
_positive_or_default = _positive_or_minus_one("an integer >= 1 or -1 (the default)")


def _add_num_threads(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--num-threads",
        type=_positive_or_default,
        default=1,
        help="torch threads (default: 1, fastest for these small networks); -1: torch's default",
    )


def _set_num_threads(args: argparse.Namespace) -> None:
    import torch

    if args.num_threads > 0:
        torch.set_num_threads(args.num_threads)


def _check_device(device: str) -> None:
    """``--device``: auto, or a torch device this machine has."""
    import torch

    if device == "auto":
        return
    try:
        parsed = torch.device(device)
    except (RuntimeError, ValueError):
        raise UsageError(f"--device: invalid device {device!r}: expected auto, cpu, cuda or cuda:<index>.") from None
    if parsed.type == "cuda" and not torch.cuda.is_available():
        raise UsageError(f"--device: {device!r} asked for, but this machine has no CUDA GPU: use auto or cpu.")


def _check_folder(flag: str, path: str | None) -> None:
    """A folder the command may write into: not a file, no over-long name, and its nearest existing
    folder writable (checked before anything is created)."""
    if not path:
        return
    try:
        path.encode("utf-8")
    except UnicodeEncodeError:
        raise UsageError(f"{flag}: {path!r} is not a valid UTF-8 path (the logs and configs name it).") from None
    if os.path.exists(path) and not os.path.isdir(path):
        raise UsageError(f"{flag}: {path!r} is a file, expected a folder.")
    too_long = [part for part in Path(path).parts if len(os.fsencode(part)) > 255]
    if too_long or len(os.fsencode(os.path.abspath(path))) > 4000:
        raise UsageError(f"{flag}: {path!r} is too long a path (at most 255 bytes per folder name).")
    existing = Path(os.path.abspath(path))
    while not existing.exists():
        existing = existing.parent
    if not os.access(existing, os.W_OK | os.X_OK):
        raise UsageError(f"{flag}: {path!r} cannot be written: {str(existing)!r} is not writable.")
    try:  # a real folder can be made there (not so in /proc, on a read-only mount, ...): probe and remove
        os.rmdir(tempfile.mkdtemp(prefix=".sb3-marl-probe-", dir=existing))
    except OSError as error:
        raise UsageError(
            f"{flag}: {path!r} cannot be written: no folder can be made in {str(existing)!r} ({error.strerror})."
        ) from None


def _check_file(flag: str, path: str | Path | None) -> None:
    """A file the command will write (atomically, through a temporary file beside it): not a folder
    or a device, and its folder writable (checked before the work)."""
    if not path:
        return
    if os.path.isdir(path):
        raise UsageError(f"{flag}: {str(path)!r} is a folder, expected a file name.")
    if os.path.exists(path) and not os.path.isfile(path):
        raise UsageError(f"{flag}: {str(path)!r} is not a regular file (a device or a pipe): give a file name.")
    _check_folder(flag, os.path.dirname(os.path.abspath(path)))


#: Seeds numpy and the scenario accept: 0 <= seed < 2**32 (episode seeds add 10,000 for evaluation).
MAX_SEED = 2**32 - 1 - 100_000


def _check_seed(seed: int) -> None:
    if not 0 <= seed <= MAX_SEED:
        raise UsageError(f"--seed: invalid seed {seed}: expected an integer in [0, {MAX_SEED}].")


def _add_run_selection(parser: argparse.ArgumentParser) -> None:
    """rl-zoo ``enjoy``'s flags to pick a trained model."""
    parser.add_argument("--algo", default="ma2c", choices=ALGO_NAMES, help="learner (default: ma2c)")
    parser.add_argument("--env", default=DEFAULT_ENV, choices=list(ENV_IDS.values()), help="scenario id")
    parser.add_argument("-f", "--folder", "--log-folder", dest="folder", default="logs", help="log folder (default: logs)")
    parser.add_argument("--exp-id", type=int, default=0, help="run id; 0 = latest (default)")
    picked = parser.add_mutually_exclusive_group()
    picked.add_argument("--load-best", action="store_true", help="load best_model.zip")
    picked.add_argument("--load-checkpoint", type=int, metavar="STEPS", help="load rl_model_<STEPS>_steps.zip")
    picked.add_argument("--load-last-checkpoint", action="store_true", help="load the latest checkpoint")
    parser.add_argument("--seed", type=int, default=0, help="episode seeds start at seed + 10000 (default: 0)")
    parser.add_argument(
        "--deterministic",
        action="store_true",
        help="argmax actions (default: sampled from the policy, the authors' evaluation protocol)",
    )
    parser.add_argument("--device", default="auto", help="torch device (default: auto)")
    _add_trust_remote_code(parser)
    _add_num_threads(parser)


def _add_trust_remote_code(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--trust-remote-code",
        action="store_true",
        help="load a model zip from another tool that needs unpickling (it can run code: only for "
        "files you trust); default: models are read as data and such a zip is refused",
    )


class _CommandParser(argparse.ArgumentParser):
    """A subcommand's parser, showing defaults in its ``--help``."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("formatter_class", _DefaultsHelpFormatter)
        super().__init__(*args, **kwargs)


class _DefaultsHelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """argparse's defaults in ``--help`` (as rl-zoo users expect), unless the help already says
    what the default is or there is none to show."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        if (
            "default" in text.lower()
            or action.default is None
            or action.default is False
            or action.default == argparse.SUPPRESS
        ):
            return text
        return super()._get_help_string(action)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="sb3-marl",
        description="Multi-agent RL for cooperative lane changing of CAVs",
        formatter_class=_DefaultsHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND", parser_class=_CommandParser)

    train = commands.add_parser("train", help="train a learner (rl-zoo's train.py flags)")
    train.add_argument("--algo", default="ma2c", choices=ALGO_NAMES, help="learner (default: ma2c)")
    train.add_argument("--env", default=DEFAULT_ENV, choices=list(ENV_IDS.values()), help="scenario id")
    train.add_argument(
        "-n",
        "--n-timesteps",
        type=_positive_or_default,
        default=-1,
        help="AV-steps to train (>= 1); -1: the config's n_timesteps",
    )
    train.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    train.add_argument("-f", "--log-folder", default="logs", help="log folder (default: logs)")
    train.add_argument(
        "-tb", "--tensorboard-log", default=None, help="TensorBoard folder (default: <log-folder>/tensorboard; '' disables)"
    )
    train.add_argument("--eval-freq", type=_every, default=10_000, help="evaluate every N AV-steps; -1 disables")
    train.add_argument(
        "--eval-episodes", type=_positive(maximum=MAX_EPISODES), default=5, help="episodes per evaluation (default: 5)"
    )
    train.add_argument("--save-freq", type=_every, default=-1, help="checkpoint every N AV-steps; -1 disables")
    train.add_argument("-c", "--conf-file", default=None, help="YAML instead of zoo_configs/<algo>.yml")
    train.add_argument(
        "-params",
        "--hyperparams",
        nargs="+",
        action=StoreHyperparams,
        default={},
        metavar="KEY:VALUE",
        help="override hyperparameters, e.g. n_steps:20 reward_mode:'global'",
    )
    train.add_argument("-i", "--trained-agent", default="", help="continue training this model zip (counts on)")
    train.add_argument(
        "--vec-env", default="dummy", choices=["dummy", "subproc"], help="scenario copies in process or in workers"
    )
    train.add_argument(
        "--n-envs", type=_positive(maximum=MAX_COPIES), default=None, help="scenario copies (default: the config's)"
    )
    train.add_argument(
        "--reward-mode", choices=["local", "global", "individual"], default=None, help="overrides the config's reward_mode"
    )
    train.add_argument("--progress", action="store_true", help="progress bar (tqdm + rich)")
    train.add_argument("--device", default="auto", help="torch device (default: auto)")
    _add_trust_remote_code(train)
    _add_num_threads(train)
    train.add_argument(
        "--log-interval", type=_positive_or_default, default=-1, help="SB3 log_interval (>= 1); -1: the algorithm's default"
    )
    train.add_argument(
        "--verbose",
        type=int,
        default=1,
        choices=[0, 1, 2],
        help="0: quiet; 1 (default): set-up, progress and evaluation lines; 2: also SB3's logger tables",
    )
    search = train.add_argument_group("hyperparameter search (rl-zoo's -optimize, Optuna)")
    search.add_argument(
        "-optimize",
        "--optimize-hyperparameters",
        action="store_true",
        help="search hyperparameters instead of training one model",
    )
    search.add_argument("--n-trials", type=_positive(maximum=MAX_COUNT), default=500, help="trials to run (default: 500)")
    search.add_argument(
        "--n-jobs", type=_positive(maximum=MAX_COPIES), default=1, help="trials in parallel (threads; default: 1)"
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
        type=_positive(),
        default=None,
        help="evaluations per trial, for pruning (default: one per 100k AV-steps)",
    )
    search.add_argument(
        "--storage", default=None, help="database URL (sqlite:///study.db) or .log journal file; a study is resumed from it"
    )
    search.add_argument("--study-name", default=None, help="study name in --storage (required with it)")

    for name in ("evaluate", "enjoy"):
        evaluate = commands.add_parser(
            name,
            help="evaluate a trained model on seeded episodes" if name == "evaluate" else "alias of evaluate (rl-zoo's name)",
        )
        _add_run_selection(evaluate)
        evaluate.add_argument(
            "--eval-episodes", type=_positive(maximum=MAX_EPISODES), default=30, help="episodes (default: 30)"
        )
        evaluate.add_argument("-o", "--output", default=None, help="JSON file (default: <run>/evaluation.json)")
        evaluate.add_argument(
            "--with-baselines",
            nargs="*",
            default=None,
            metavar="POLICY",
            choices=["random", "cruise", "idm-mobil"],
            help="add reference policies on the same seeds to the table: the ones named, or all of "
            "them (random, cruise, idm-mobil) without a name",
        )

    plot = commands.add_parser("plot", help="learning-curve PNGs of one or several runs")
    plot.add_argument(
        "--algo", "--algos", dest="algos", nargs="+", default=["ma2c"], choices=ALGO_NAMES, help="learners to plot"
    )
    plot.add_argument("--env", default=DEFAULT_ENV, choices=list(ENV_IDS.values()), help="scenario id")
    plot.add_argument("-f", "--folder", "--log-folder", dest="folder", default="logs", help="log folder of the runs")
    plot.add_argument("--exp-ids", type=int, nargs="+", default=None, help="runs to plot (default: all)")
    plot.add_argument("-w", "--episode-window", type=_positive(), default=100, help="rolling window of training returns")
    plot.add_argument("-o", "--output", default=None, help="folder for the PNGs (default: <folder>/plots)")

    video = commands.add_parser("record-video", help="mp4 of evaluation episodes, rendered headless")
    _add_run_selection(video)
    video.add_argument("--n-episodes", type=_positive(maximum=MAX_COUNT), default=1, help="episodes in the video (default: 1)")
    video.add_argument("-o", "--output", default=None, help="mp4 file (default: <run>/videos/<model>.mp4)")

    push = commands.add_parser("push-to-hub", help="build a model folder with a model card and upload it (rl-zoo's flags)")
    _add_run_selection(push)
    push.add_argument("--repo-name", default=None, help="default: <algo>-<env name>")
    push.add_argument("-orga", "--organization", required=True, help="Hub user or organisation")
    push.add_argument("-m", "--commit-message", default="Upload sb3-marl model", help="the Hub commit's message")
    push.add_argument(
        "--eval-episodes", type=_positive(maximum=MAX_EPISODES), default=10, help="episodes of the card's evaluation"
    )
    push.add_argument("--no-video", action="store_true", help="leave replay.mp4 out")
    push.add_argument("--private", action="store_true", help="create the Hub repo private")
    push.add_argument("--dry-run", metavar="PATH", default=None, help="only build the folder at PATH")

    summary = commands.add_parser("summary", help="markdown table of the evaluated runs of a log folder")
    summary.add_argument("-f", "--folder", "--log-folder", dest="folder", default="logs", help="log folder of the runs")
    summary.add_argument("-o", "--output", default=None, help="markdown file (default: <folder>/summary.md)")

    load = commands.add_parser("load-from-hub", help="download a model into the log layout (then evaluate/enjoy it)")
    load.add_argument("--repo-id", required=True, help="ORG/NAME")
    load.add_argument("-f", "--folder", "--log-folder", dest="folder", default="logs", help="log folder to place the run in")

    baselines = commands.add_parser("baselines", help="metrics of the reference policies (random, cruise, IDM/MOBIL)")
    baselines.add_argument("--density", type=int, choices=sorted(DENSITIES), default=1, help="traffic density")
    baselines.add_argument(
        "--episodes", type=_positive(maximum=MAX_EPISODES), default=20, help="episodes per policy and AV count"
    )
    baselines.add_argument("--seed", type=int, default=0, help="first episode seed")
    baselines.add_argument(
        "--out", type=Path, default=Path("logs/scenario_baselines.md"), help="markdown table (and .json beside)"
    )

    benchmark = commands.add_parser(
        "benchmark", help="the paper's experiment grid as Ray Tune trials; `benchmark report` writes its table and figures"
    )
    benchmark.add_argument(
        "action",
        nargs="?",
        choices=["run", "report", "status", "evaluate"],
        default="run",
        help="run the grid (default), report on it, list where its trials stand, or evaluate "
        "its finished trials under both supervisor protocols where they lack one or predate the current supervisor",
    )
    benchmark.add_argument(
        "--grid",
        default="paper",
        choices=list(GRIDS),
        help="paper (the five experiments of the paper and our intervention-penalty one) or one experiment (default: paper)",
    )
    benchmark.add_argument("-f", "--log-folder", default="logs/benchmark", help="default: logs/benchmark")
    benchmark.add_argument(
        "--budget", type=_budget, default=1.0, help="fraction of the paper's 1M env steps per trial (default: 1)"
    )
    benchmark.add_argument(
        "--seeds", type=_positive(maximum=MAX_COUNT), default=PAPER_SEEDS, help="seeds per trial setting (default: 2)"
    )
    benchmark.add_argument(
        "--densities", type=int, nargs="+", choices=sorted(DENSITIES), default=sorted(DENSITIES), help="traffic densities"
    )
    benchmark.add_argument(
        "--eval-every",
        type=_positive(float),
        default=PAPER_EVAL_EVERY_EPISODES,
        metavar="EPISODES",
        help="evaluate every N training episodes (default: 200, the paper's)",
    )
    benchmark.add_argument(
        "--eval-episodes",
        type=_positive(),
        default=PAPER_EVAL_EPISODES,
        help="episodes per evaluation (default: 3, the paper's)",
    )
    benchmark.add_argument("--address", default=None, help="attach to this Ray cluster (default: a local Ray)")
    benchmark.add_argument(
        "--max-concurrent", type=_positive(maximum=MAX_COPIES), default=None, help="trials at once (default: one per free CPU)"
    )
    benchmark.add_argument("--max-failures", type=int, default=2, help="restarts of a failed trial (default: 2)")
    benchmark.add_argument("-o", "--output", default="results", help="report: output folder (default: results)")
    benchmark.add_argument("--verbose", type=int, default=1, choices=[0, 1, 2], help="Ray Tune's verbosity")
    return parser


def _budget(text: str) -> float:
    from sb3_marl.benchmark.grid import check_budget

    try:
        return check_budget(float(text))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected a fraction in (0, 1] of the paper's 1M env steps per trial, got {text!r}"
        ) from None


# ---- train -------------------------------------------------------------------------------------


class _StopTraining:
    """While active, SIGTERM raises KeyboardInterrupt like Ctrl-C, so training stops and saves."""

    def __init__(self) -> None:
        self.signal: int | None = None

    def __enter__(self) -> _StopTraining:
        self._previous = {sig: signal.signal(sig, self._handle) for sig in EXIT_INTERRUPTED}
        return self

    def _handle(self, signum: int, frame: Any) -> None:
        if self.signal is None:
            self.signal = signum
            raise KeyboardInterrupt

    def __exit__(self, *exc: Any) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)


def _check_train_args(args: argparse.Namespace) -> None:
    """Everything about ``train``'s flags that can be checked before any work or folder."""
    from sb3_marl.algos import get_algo
    from sb3_marl.loading import safe_custom_objects
    from sb3_marl.runs import check_model_file

    _check_seed(args.seed)
    _check_folder("-f/--log-folder", args.log_folder)
    _check_folder("-tb/--tensorboard-log", args.tensorboard_log)
    _check_device(args.device)
    if args.conf_file and not os.path.isfile(args.conf_file):
        raise UsageError(f"-c/--conf-file: {args.conf_file!r} is not an existing YAML file.")
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
    from sb3_marl.hyperparams import load_hyperparams, merge_hyperparams
    from sb3_marl.loading import UnsafeModelError, read_run_yaml
    from sb3_marl.runs import check_observation_shape

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


def train(args: argparse.Namespace) -> int:
    from sb3_marl.experiment import MARLExperimentManager

    _check_train_args(args)
    _set_num_threads(args)
    tensorboard_log = os.path.join(args.log_folder, "tensorboard") if args.tensorboard_log is None else args.tensorboard_log
    manager = MARLExperimentManager(
        args,
        args.algo,
        args.env,
        args.log_folder,
        conf_file=args.conf_file,
        n_copies=args.n_envs,
        reward_mode=args.reward_mode,
        vec_env_type=args.vec_env,
        tensorboard_log=tensorboard_log,
        n_timesteps=args.n_timesteps,
        eval_freq=args.eval_freq,
        n_eval_episodes=args.eval_episodes,
        save_freq=args.save_freq,
        hyperparams=args.hyperparams,
        trained_agent=args.trained_agent,
        seed=args.seed,
        log_interval=args.log_interval,
        verbose=args.verbose,
        device=args.device,
        show_progress=args.progress,
        trust_remote_code=args.trust_remote_code,
        optimize_hyperparameters=args.optimize_hyperparameters,
        n_trials=args.n_trials,
        n_jobs=args.n_jobs,
        sampler=args.sampler,
        pruner=args.pruner,
        n_startup_trials=args.n_startup_trials,
        n_evaluations=args.n_evaluations,
        storage=args.storage,
        study_name=args.study_name,
    )
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
    with _StopTraining() as stop:
        try:
            manager.learn(model)
        except OSError as error:  # a full disk, a folder removed under us: saving would likely fail too
            raise CommandFailed(_write_failure(manager, model, error)) from None
        except Exception as error:  # a dead worker, a NaN, ...: keep what was learnt, then report
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
    print(f"Training wall time: {time.perf_counter() - start:.1f} s, {model.num_timesteps} timesteps (AV-steps)")
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
    from sb3_marl.runs import latest_checkpoint

    where = f" ({error.filename})" if error.filename else ""
    checkpoint = latest_checkpoint(manager.save_path)
    resume = (
        f"The last complete checkpoint is {checkpoint}: free some space, then continue with -i {checkpoint}."
        if checkpoint
        else "No checkpoint was written (--save-freq saves them); free some space and train again."
    )
    return (
        f"could not write{where} at {model.num_timesteps} timesteps: {error.strerror or error}. "
        f"The model of this moment could not be saved. {resume}"
    )


# ---- evaluate, record-video, plot, baselines ----------------------------------------------------


def _find_run(args: argparse.Namespace) -> Any:
    from sb3_marl.runs import find_run

    _check_seed(args.seed)
    try:
        return find_run(
            args.folder, args.algo, args.env, args.exp_id, args.load_best, args.load_checkpoint, args.load_last_checkpoint
        )
    except (FileNotFoundError, ValueError) as error:
        raise UsageError(str(error)) from None


def _load_model(run: Any, args: argparse.Namespace) -> Any:
    """The run's model on ``--device`` with ``--num-threads``; a usage error naming a bad file."""
    _check_device(args.device)
    _set_num_threads(args)
    try:
        return run.load_model(args.device, args.trust_remote_code)
    except ValueError as error:
        raise UsageError(str(error)) from None


def evaluate(args: argparse.Namespace) -> int:
    from sb3_marl.evaluation import evaluate_protocols, markdown_table, protocol_rows
    from sb3_marl.experiment import EVAL_SEED_OFFSET

    _check_file("-o/--output", args.output)
    run = _find_run(args)
    model = _load_model(run, args)
    seed = args.seed + EVAL_SEED_OFFSET
    start = time.perf_counter()
    result = {"model": str(run.model_path), **run.evaluate(model, args.eval_episodes, seed, args.deterministic, progress=True)}
    rows = protocol_rows({"policy": args.algo, "timesteps": model.num_timesteps}, result)
    if args.with_baselines is not None:
        from sb3_marl.baselines import BASELINES

        result["baselines"] = {}
        for name, policy_class in BASELINES.items():
            if args.with_baselines and name not in args.with_baselines:
                continue
            baseline = evaluate_protocols(policy_class(), args.env, args.eval_episodes, seed, run.env_config, progress=True)
            result["baselines"][name] = baseline
            rows += protocol_rows({"policy": name, "timesteps": "-"}, baseline)
    heading = (
        f"{args.env}: {args.eval_episodes} episodes, seeds {seed}..{seed + args.eval_episodes - 1}, "
        f"{result['protocol']} (on: the authors' protocol; off: the policy alone); model {run.model_path}"
    )
    table = markdown_table(rows)
    print(heading + "\n")
    print(table)
    output = Path(args.output) if args.output else run.log_path / "evaluation.json"
    write_text(output, json.dumps(result, indent=2))
    write_text(output.with_suffix(".md"), heading + "\n\n" + table + "\n")
    print(f"\nwrote {output} and {output.with_suffix('.md')} ({time.perf_counter() - start:.1f} s)")
    return 0


def record_video_command(args: argparse.Namespace) -> int:
    from sb3_marl.evaluation import model_policy
    from sb3_marl.experiment import EVAL_SEED_OFFSET
    from sb3_marl.video import record_video

    run = _find_run(args)
    model = _load_model(run, args)
    output = Path(args.output) if args.output else run.log_path / "videos" / f"{run.model_path.stem}.mp4"
    _check_file("-o/--output", output)
    try:
        info = record_video(
            model_policy(model, args.deterministic),
            args.env,
            output,
            args.n_episodes,
            args.seed + EVAL_SEED_OFFSET,
            run.env_config,
        )
    except (OSError, RuntimeError) as error:  # ffmpeg missing, broken or refusing the file
        raise CommandFailed(
            f"could not write the video {output} with ffmpeg ({type(error).__name__}: "
            f"{str(error).strip().splitlines()[-1] if str(error).strip() else error}); check the "
            "ffmpeg that imageio-ffmpeg uses (IMAGEIO_FFMPEG_EXE)."
        ) from None
    print(f"wrote {info['path']}: {info['episodes']} episode(s), {info['frames']} frames at {info['fps']} fps")
    return 0


def push_to_hub(args: argparse.Namespace) -> int:
    from rl_zoo3.utils import EnvironmentName

    from sb3_marl.experiment import EVAL_SEED_OFFSET
    from sb3_marl.hub import HubError, build_model_folder, push_folder

    repo_id = f"{args.organization}/{args.repo_name or f'{args.algo}-{EnvironmentName(args.env)}'}"
    _check_repo_id("-orga/--organization and --repo-name", repo_id)
    dry_run = args.dry_run
    occupied = os.path.exists(dry_run or "") and (not os.path.isdir(dry_run) or bool(os.listdir(dry_run)))
    if dry_run and (os.path.islink(dry_run) or occupied):
        raise UsageError(f"--dry-run: {args.dry_run!r} exists and is not an empty folder: give a new or empty folder.")
    run = _find_run(args)
    model = _load_model(run, args)  # a clear error for an unreadable model, before building anything
    folder = Path(args.dry_run) if args.dry_run else fresh_folder(run.log_path / "hub")
    build_model_folder(run, folder, repo_id, args.eval_episodes, args.seed + EVAL_SEED_OFFSET, not args.no_video, model)
    print(f"built the model folder {folder} for {repo_id}")
    if args.dry_run:
        return 0
    try:
        url = push_folder(folder, repo_id, args.commit_message, private=args.private)
    except HubError as error:
        raise CommandFailed(str(error)) from None
    print(f"uploaded to {url}")
    return 0


def fresh_folder(folder: Path) -> Path:
    """``folder`` emptied and created anew: whatever was there (an earlier build, files or links
    put there, a link to another folder) is removed without following links, so the upload holds
    only the files built for it."""
    if folder.is_symlink() or folder.is_file():
        folder.unlink()
    elif folder.exists():
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    return folder


def _check_repo_id(flag: str, repo_id: str) -> None:
    from huggingface_hub.utils import HFValidationError, validate_repo_id

    try:
        validate_repo_id(repo_id)
    except HFValidationError as error:
        raise UsageError(f"{flag}: invalid Hub repo id {repo_id!r}: {error}") from None
    if repo_id.count("/") != 1:
        raise UsageError(f"{flag}: invalid Hub repo id {repo_id!r}: expected ORG/NAME.")


def load_from_hub_command(args: argparse.Namespace) -> int:
    from sb3_marl.hub import HubError, load_from_hub

    _check_repo_id("--repo-id", args.repo_id)

    try:
        run = load_from_hub(args.repo_id, args.folder)
    except HubError as error:
        raise CommandFailed(str(error)) from None
    print(f"downloaded {args.repo_id} into {run}")
    return 0


def plot(args: argparse.Namespace) -> int:
    from sb3_marl.plotting import plot_runs
    from sb3_marl.runs import run_folders, run_id, run_overrides

    runs = {}
    for algo in args.algos:
        for folder in run_folders(args.folder, algo, args.env):
            if args.exp_ids is None or run_id(folder) in args.exp_ids:
                try:
                    overrides = run_overrides(folder, args.env)
                except ValueError as error:  # an args.yml that is not plain data: named, never read
                    raise UsageError(str(error)) from None
                runs[f"{algo} run {run_id(folder)}" + (f" ({overrides})" if overrides else "")] = folder
    if not runs:
        raise UsageError(f"No runs of {args.algos} on {args.env} under {args.folder}/ (exp ids: {args.exp_ids or 'all'}).")
    try:
        written = plot_runs(runs, args.output or os.path.join(args.folder, "plots"), args.episode_window)
    except ValueError as error:
        raise UsageError(str(error)) from None
    for path in written:
        print(f"wrote {path}")
    return 0


def summary(args: argparse.Namespace) -> int:
    from sb3_marl.runs import summary_table

    if not os.path.isdir(args.folder):
        raise UsageError(f"-f/--folder: {args.folder!r} is not a folder.")
    try:
        table = summary_table(args.folder)
    except ValueError as error:  # an unreadable (or unsafe) evaluation.json / args.yml: named
        raise UsageError(str(error)) from None
    if table.count("\n") < 2:
        raise UsageError(f"No evaluated run under {args.folder}/ (run `sb3-marl evaluate` on a run first).")
    output = Path(args.output) if args.output else Path(args.folder) / "summary.md"
    _check_file("-o/--output", output)
    write_text(output, table + "\n")
    print(table)
    print(f"\nwrote {output}")
    return 0


def baselines(args: argparse.Namespace) -> int:
    _check_file("--out", args.out)
    from sb3_marl.baselines import BASELINES
    from sb3_marl.evaluation import markdown_table, run_episodes, summarize

    lo, hi = DENSITIES[args.density]["avs"]
    rows, results = [], []
    start = time.perf_counter()
    for name, policy_class in BASELINES.items():
        for n_avs in range(lo, hi + 1):
            env = make_scenario(ENV_IDS[args.density], {"n_avs": n_avs})
            summary = summarize(run_episodes(env, policy_class(), args.episodes, seed=args.seed))
            results.append({"policy": name, "n_avs": n_avs, **summary})
            rows.append(({"policy": name, "n_avs": n_avs}, summary))
    table = (
        f"Scenario {ENV_IDS[args.density]}: {args.episodes} episodes per row, "
        f"seeds {args.seed}..{args.seed + args.episodes - 1}\n\n" + markdown_table(rows)
    )
    print(table)
    write_text(args.out, table + "\n")
    write_text(args.out.with_suffix(".json"), json.dumps(results, indent=2))
    print(f"\nwrote {args.out} and {args.out.with_suffix('.json')} in {time.perf_counter() - start:.1f} s")
    return 0


def benchmark(args: argparse.Namespace) -> int:
    if args.action == "report":
        from sb3_marl.benchmark.report import write_report

        try:
            written = write_report(args.log_folder, args.output)
        except (FileNotFoundError, ValueError) as error:
            raise UsageError(str(error)) from None
        for path in written:
            print(f"wrote {path}")
        return 0

    if args.action == "status":
        return _benchmark_status(args)

    if args.action == "evaluate":
        return _benchmark_evaluate(args)

    from sb3_marl.benchmark.runner import run_benchmark

    try:
        outcome = run_benchmark(
            args.grid,
            args.log_folder,
            args.budget,
            args.seeds,
            tuple(args.densities),
            args.eval_every,
            args.eval_episodes,
            args.address,
            args.max_concurrent,
            args.max_failures,
            args.verbose,
        )
    except ValueError as error:
        raise UsageError(str(error)) from None
    except ModuleNotFoundError as error:
        raise CommandFailed(str(error)) from None
    print(
        f"{len(outcome.completed)} trials completed, {len(outcome.skipped)} skipped (finished before), "
        f"{len(outcome.failed)} failed, {len(outcome.unfinished)} stopped unfinished in {outcome.wall_time_s:.0f} s"
    )
    for trial_id, message in outcome.failed.items():
        print(f"  failed: {trial_id}: {message.splitlines()[0]}")
    print(f"report: sb3-marl benchmark report -f {args.log_folder}")
    if outcome.failed:
        raise CommandFailed(
            f"{len(outcome.failed)} trial(s) failed after {args.max_failures} restarts: "
            f"{sorted(outcome.failed)}; run the command again to retry them."
        )
    if outcome.unfinished:
        print(f"{len(outcome.unfinished)} trial(s) stopped before the end; the same command continues them.")
        return EXIT_INTERRUPTED[signal.SIGINT]
    return 0


def _benchmark_evaluate(args: argparse.Namespace) -> int:
    """Re-evaluate every finished trial under ``-f`` that lacks the policy-alone protocol or was
    evaluated under another version of the safety supervisor (progress bar)."""
    from tqdm import tqdm

    from sb3_marl.benchmark.trial import RESULT, reevaluate_trial

    results = sorted(Path(args.log_folder).glob(f"trials/*/{RESULT}"))
    if not results:
        raise UsageError(f"-f/--log-folder: no finished trial (trials/*/{RESULT}) under {args.log_folder!r}.")
    _set_num_threads(argparse.Namespace(num_threads=1))
    try:
        done = [path.parent.name for path in tqdm(results, desc="trials", unit="trial") if reevaluate_trial(path.parent)]
    except (ValueError, KeyError, TypeError) as error:  # an unreadable or edited result.json, named
        raise UsageError(f"-f/--log-folder: {error}") from None
    print(
        f"re-evaluated {len(done)} of {len(results)} finished trials under both supervisor protocols (the current supervisor)"
    )
    return 0


def _benchmark_status(args: argparse.Namespace) -> int:
    """Print each trial of ``--grid`` in ``-f``: state, AV-steps of the budget, final return, wall time."""
    from sb3_marl.benchmark.runner import grid_status

    try:
        statuses = grid_status(args.grid, args.log_folder, args.seeds, tuple(args.densities))
    except (FileNotFoundError, ValueError) as error:
        raise UsageError(str(error)) from None
    counts = {
        state: sum(s.state == state for s in statuses) for state in ("finished", "unfinished", "not started", "unreadable")
    }
    print(
        f"Benchmark grid {args.grid!r} in {args.log_folder}: {counts['finished']} of {len(statuses)} trials finished, "
        f"{counts['unfinished']} unfinished (continue from their checkpoint), {counts['not started']} not started"
        + (f", {counts['unreadable']} with an unreadable result" if counts["unreadable"] else "")
        + "\n"
    )
    width = max(len(s.trial_id) for s in statuses)
    print(f"{'trial':<{width}}  {'state':<11}  {'AV-steps done':>25}  {'return':>7}  {'wall time':>9}")
    for s in statuses:
        done = f"{s.timesteps:,} / {s.n_timesteps:,}"
        returns = f"{s.return_mean:.2f}" if s.return_mean is not None else "-"
        wall = f"{s.wall_time_s:.0f} s" if s.wall_time_s is not None else "-"
        print(f"{s.trial_id:<{width}}  {s.state:<11}  {done:>25}  {returns:>7}  {wall:>9}")
    for s in statuses:
        if s.problem:
            print(f"unreadable: {s.problem}", file=sys.stderr)
    return 1 if counts["unreadable"] else 0


class UsageError(Exception):
    """Bad input found before any work: printed as ``sb3-marl <command>: error: ...``, exit code 2."""


class CommandFailed(Exception):
    """The work could not be done (e.g. no Hub token, network error): printed like a UsageError, exit code 1."""


COMMANDS = {
    "train": train,
    "evaluate": evaluate,
    "enjoy": evaluate,
    "plot": plot,
    "record-video": record_video_command,
    "push-to-hub": push_to_hub,
    "load-from-hub": load_from_hub_command,
    "baselines": baselines,
    "benchmark": benchmark,
    "summary": summary,
}


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
    try:
        return COMMANDS[args.command](args)
    except (UsageError, CommandFailed) as error:
        print(f"sb3-marl {args.command}: error: {error}", file=sys.stderr)
        return 2 if isinstance(error, UsageError) else 1
    except (KeyboardInterrupt, SystemError) as error:  # numba reports Ctrl-C in compiled code as a SystemError
        from sb3_marl.experiment import interrupted_by_user

        if not interrupted_by_user(error):
            raise
        print(
            f"sb3-marl {args.command}: interrupted; files it had written are complete (each is written whole), "
            "nothing else was written.",
            file=sys.stderr,
        )
        return EXIT_INTERRUPTED[signal.SIGINT]
    except BrokenPipeError:  # `sb3-marl ... | head` closed the pipe: stop quietly, as other tools do
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no error when Python flushes at exit
        return 1


if __name__ == "__main__":
    sys.exit(main())
