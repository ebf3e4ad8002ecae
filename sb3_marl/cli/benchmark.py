"""``sb3-marl benchmark``: the paper's experiment grid as Ray Tune trials, its status, evaluation and report."""

from __future__ import annotations

import argparse
import re
import signal
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sb3_marl.benchmark.grid import GRID_SEEDS, GRIDS, PAPER_EVAL_EPISODES, PAPER_EVAL_EVERY_EPISODES
from sb3_marl.cli.common import (
    EXIT_INTERRUPTED,
    MAX_COPIES,
    MAX_COUNT,
    MAX_EPISODES,
    CommandFailed,
    UsageError,
    check_readable,
    positive,
    set_num_threads,
)
from sb3_marl.envs import DENSITIES

if TYPE_CHECKING:
    from sb3_marl.benchmark.storage import GridStorage


def add_parsers(commands: Any) -> None:
    """Add benchmark's subcommands to the ``sb3-marl`` parser's ``commands``."""
    benchmark = commands.add_parser(
        "benchmark", help="the paper's experiment grid as Ray Tune trials; `benchmark report` writes its table and figures"
    )
    benchmark.add_argument(
        "action",
        nargs="?",
        choices=["run", "report", "status", "evaluate"],
        default=None,
        help="run the grid (default when --grid is given), report on it, list where its trials stand, or evaluate "
        "its finished trials under both supervisor protocols where they lack one or the traffic metrics, or predate the "
        "current supervisor",
    )
    benchmark.add_argument(
        "--grid",
        default=None,
        choices=list(GRIDS),
        help="paper (the five experiments of the paper and our intervention-penalty one) or one experiment (default: paper)",
    )
    benchmark.add_argument("-f", "--log-folder", default="logs/benchmark", help="default: logs/benchmark")
    benchmark.add_argument(
        "--budget", type=_budget, default=1.0, help="fraction of the paper's 1M env steps per trial (default: 1)"
    )
    benchmark.add_argument(
        "--seeds",
        type=positive(maximum=MAX_COUNT),
        default=None,
        help=f"seeds per trial setting (default: {GRID_SEEDS}; status: as many as -f holds, at least {GRID_SEEDS})",
    )
    benchmark.add_argument(
        "--densities", type=int, nargs="+", choices=sorted(DENSITIES), default=sorted(DENSITIES), help="traffic densities"
    )
    benchmark.add_argument(
        "--eval-every",
        type=positive(float),
        default=PAPER_EVAL_EVERY_EPISODES,
        metavar="EPISODES",
        help="evaluate every N training episodes (default: 200, the paper's)",
    )
    benchmark.add_argument(
        "--eval-episodes",
        type=positive(maximum=MAX_EPISODES),
        default=PAPER_EVAL_EPISODES,
        help="episodes per evaluation (default: 3, the paper's)",
    )
    benchmark.add_argument("--address", default=None, help="attach to this Ray cluster (default: a local Ray)")
    benchmark.add_argument(
        "--storage",
        default=None,
        metavar="URI",
        help="keep the grid in this storage (s3://bucket/grid, gs://..., file:///...; credentials from the environment), "
        "for a cluster without a shared disk; -f is then the local copy that status, report and evaluate download into",
    )
    benchmark.add_argument(
        "--max-concurrent", type=positive(maximum=MAX_COPIES), default=None, help="trials at once (default: one per free CPU)"
    )
    benchmark.add_argument(
        "--max-failures",
        type=positive(minimum=0, maximum=MAX_COUNT),
        default=2,
        help="restarts of a failed trial (default: 2)",
    )
    benchmark.add_argument(
        "--wait", action="store_true", help="wait for another launcher running the same -f to end (default: refuse)"
    )
    benchmark.add_argument("-o", "--output", default="results", help="report: output folder (default: results)")
    benchmark.add_argument("--verbose", type=int, default=1, choices=[0, 1, 2], help="Ray Tune's verbosity")
    benchmark.set_defaults(handler=benchmark_command)


def _budget(text: str) -> float:
    from sb3_marl.benchmark.grid import check_budget

    try:
        return check_budget(float(text))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected a fraction in (0, 1] of the paper's 1M env steps per trial, got {text!r}"
        ) from None


def benchmark_command(args: argparse.Namespace) -> int:
    if args.action is None and args.grid is None:
        raise UsageError(
            "sb3-marl benchmark with neither an action nor --grid would start the whole paper grid at its full "
            "budget (81 trials of 1M env steps with --seeds 3: hours of every core). Start it with "
            "`sb3-marl benchmark --grid paper` (or `run`); `--budget 0.01` runs a short one; `status`, "
            "`report` and `evaluate` read a grid folder."
        )
    args.action, args.grid = args.action or "run", args.grid or "paper"
    storage = _storage(args.storage) if args.storage else None
    if storage is not None and args.action != "run":  # the grid's trial folders, into the local copy
        downloaded = storage.download_trials(Path(args.log_folder))
        print(f"downloaded {len(downloaded)} trial folders from {storage.uri} into {args.log_folder}")
    if args.action in ("report", "status", "evaluate"):
        check_readable("-f/--log-folder", args.log_folder)
    if args.seeds is None:
        args.seeds = max(GRID_SEEDS, _seeds_in(args.log_folder)) if args.action == "status" else GRID_SEEDS
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
        return _benchmark_evaluate(args, storage)

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
            args.wait,
            args.storage,
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
    print(f"report: sb3-marl benchmark report -f {args.log_folder}" + (f" --storage {args.storage}" if storage else ""))
    if outcome.failed:
        raise CommandFailed(
            f"{len(outcome.failed)} trial(s) failed after {args.max_failures} restarts: "
            f"{sorted(outcome.failed)}; run the command again to retry them."
        )
    if outcome.unfinished:
        print(f"{len(outcome.unfinished)} trial(s) stopped before the end; the same command continues them.")
        return EXIT_INTERRUPTED[signal.SIGINT]
    return 0


def _storage(uri: str) -> GridStorage:
    from sb3_marl.benchmark.storage import GridStorage

    try:
        return GridStorage(uri)
    except ValueError as error:
        raise UsageError(str(error)) from None


def _benchmark_evaluate(args: argparse.Namespace, storage: GridStorage | None = None) -> int:
    """Re-evaluate every finished trial under ``-f`` that lacks the policy-alone protocol or the
    traffic metrics, or was evaluated under another version of the safety supervisor (progress bar); with ``storage``,
    upload the re-evaluated trials' folders there."""
    from tqdm import tqdm

    from sb3_marl.benchmark.grid import TrialSpec
    from sb3_marl.benchmark.repair import trial_damage
    from sb3_marl.benchmark.trial import reevaluate_trial
    from sb3_marl.benchmark.trial_files import RESULT, TRIAL, read_trial_info
    from sb3_marl.common.files import inside

    results = sorted(Path(args.log_folder).glob(f"trials/*/{RESULT}"))
    if not results:
        raise UsageError(f"-f/--log-folder: no finished trial (trials/*/{RESULT}) under {args.log_folder!r}.")

    def damage(folder: Path) -> list[str]:
        """Each damaged file of the trial in ``folder``, as ``status`` names it ([]: it reads back whole)."""
        try:
            spec = TrialSpec(**read_trial_info(folder / TRIAL)["trial"])
        except ValueError as error:
            return [str(error)]
        return [f"{path}: {why}" for path, why in trial_damage(Path(args.log_folder), spec).items()]

    set_num_threads(1)
    try:
        trials = [inside(path.parent, args.log_folder) for path in results]  # no link out of the grid
        damaged = {folder.name: problems for folder in trials if (problems := damage(folder))}
        whole = [folder for folder in trials if folder.name not in damaged]
        done = [folder for folder in tqdm(whole, desc="trials", unit="trial") if reevaluate_trial(folder)]
    except (ValueError, KeyError, TypeError) as error:  # an edited result.json, named
        raise UsageError(f"-f/--log-folder: {error}") from None
    if storage is not None:
        for folder in done:
            storage.upload_trial(folder, last=RESULT)
    print(f"re-evaluated {len(done)} of {len(whole)} finished trials under both supervisor protocols (the current supervisor)")
    if damaged:
        named = "; ".join(f"{trial}: {', '.join(problems)}" for trial, problems in damaged.items())
        raise CommandFailed(
            f"{len(damaged)} trial(s) with damaged files not re-evaluated ({named}); the grid's next run "
            "(`sb3-marl benchmark --grid ...` with the same -f) repairs and re-runs them."
        )
    return 0


def _seeds_in(folder: str) -> int:
    """How many seeds the trial folders in ``folder/trials`` span (``..._seed<N>``: N + 1; 0: none)."""
    trials = Path(folder) / "trials"
    seeds = [int(m[1]) for p in (trials.iterdir() if trials.is_dir() else ()) if (m := re.search(r"_seed(\d+)$", p.name))]
    return max(seeds, default=-1) + 1


def _benchmark_status(args: argparse.Namespace) -> int:
    """Print each trial of ``--grid`` in ``-f``: state, AV-steps of the budget, final return, wall time."""
    from sb3_marl.benchmark.runner import grid_status

    try:  # a storage grid's local copy keeps only its checkpoints' state.json
        statuses = grid_status(args.grid, args.log_folder, args.seeds, tuple(args.densities), args.storage is None)
    except (FileNotFoundError, ValueError) as error:
        raise UsageError(str(error)) from None
    counts = {
        state: sum(s.state == state for s in statuses) for state in ("finished", "unfinished", "not started", "unreadable")
    }
    print(
        f"Benchmark grid {args.grid!r} in {args.log_folder}: {counts['finished']} of {len(statuses)} trials finished, "
        f"{counts['unfinished']} unfinished (continue from their checkpoint), {counts['not started']} not started"
        + (f", {counts['unreadable']} with an unreadable result or other file (named below)" if counts["unreadable"] else "")
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
        for problem in s.problems:
            print(f"unreadable: {problem}", file=sys.stderr)
    return 1 if counts["unreadable"] else 0
