"""Run a grid of trials on Ray Tune: embedded local Ray by default, or an existing cluster.

Layout of the log folder (default ``logs/benchmark``)::

    benchmark.json            budget and evaluation schedule shared by all its trials
    trials/<trial id>/        one rl-zoo log folder per trial (see :mod:`sb3_marl.benchmark.trial`)
    ray/<grid>-<time>/        Ray Tune's experiment state and checkpoints

Finished trials (with ``result.json``, their files read back: :mod:`~sb3_marl.benchmark.repair`) are
skipped; unfinished ones continue from their checkpoint; damaged ones are repaired and run again.
On a multi-node cluster either the log folder is on a file system every node sees, or the grid
lives in a storage URI (``storage``: :mod:`~sb3_marl.benchmark.storage`) and the log folder is the
launcher's local copy.
"""

from __future__ import annotations

import itertools
import json
import os
import re
import socket
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import filelock

from sb3_marl.benchmark.grid import (
    GRID_SEEDS,
    PAPER_EVAL_EPISODES,
    PAPER_EVAL_EVERY_EPISODES,
    TrialSpec,
    check_budget,
    make_grid,
)
from sb3_marl.benchmark.repair import checkpoint_damage, repair_trial, trial_damage
from sb3_marl.benchmark.storage import GridStorage
from sb3_marl.benchmark.trial import run_trial
from sb3_marl.benchmark.trial_files import (
    CHECKPOINT,
    RESULT,
    TRIAL,
    checked_result,
    checkpoint_timesteps,
    read_trial_info,
    total_wall_time,
    trial_folder,
)
from sb3_marl.common.checks import check_integer, check_number
from sb3_marl.common.files import read_json_object, write_text
from sb3_marl.envs import DENSITIES

SETTINGS_FILE = "benchmark.json"
#: The launcher's lock in a grid folder (one launcher runs a grid folder at a time) and the file
#: that names its holder while it runs.
LOCK_FILE, HOLDER_FILE = ".benchmark.lock", ".benchmark.holder.json"


@dataclass
class BenchmarkRun:
    """What one invocation did: trials skipped (finished before), repaired before they ran (what was
    found and done, one line each), completed, failed for good (with the error), and left unfinished
    (the run was stopped)."""

    skipped: list[str] = field(default_factory=list)
    repaired: dict[str, str] = field(default_factory=dict)
    completed: list[str] = field(default_factory=list)
    failed: dict[str, str] = field(default_factory=dict)
    unfinished: list[str] = field(default_factory=list)
    wall_time_s: float = 0.0


def check_settings(log_folder: Path, settings: dict[str, Any], storage: GridStorage | None = None) -> None:
    """A log folder (or a grid's ``storage``) holds one budget and evaluation schedule: a ValueError
    if ``settings`` differ from those it was started with (results at different budgets do not aggregate)."""
    path = log_folder / SETTINGS_FILE
    if storage is not None:
        recorded = storage.read_json_object(SETTINGS_FILE)
    else:
        recorded = read_json_object(path) if path.is_file() else None
    if recorded is not None:
        changed = {key: (recorded.get(key), value) for key, value in settings.items() if recorded.get(key) != value}
        if changed:
            details = ", ".join(f"{key}={new!r} (it has {old!r})" for key, (old, new) in changed.items())
            raise ValueError(
                f"{log_folder} holds a benchmark with other settings: {details}; "
                "use another --log-folder or the same settings."
            )


def run_benchmark(
    grid: str = "paper",
    log_folder: str | Path = "logs/benchmark",
    budget: float = 1.0,
    seeds: int = GRID_SEEDS,
    densities: tuple[int, ...] = tuple(DENSITIES),
    eval_every_episodes: float = PAPER_EVAL_EVERY_EPISODES,
    eval_episodes: int = PAPER_EVAL_EPISODES,
    address: str | None = None,
    max_concurrent: int | None = None,
    max_failures: int = 2,
    verbose: int = 1,
    wait: bool = False,
    storage: str | None = None,
) -> BenchmarkRun:
    """Run the unfinished trials of ``grid`` as Ray Tune trials (one CPU each).

    :param grid: ``paper`` or one experiment: ``baselines``, ``reward``, ``sharing``, ``comfort``, ``politeness``
    :param budget: fraction in (0, 1] of the paper's 1M env steps per trial
    :param seeds: seeds ``0 .. seeds-1`` per (algorithm, density, variant)
    :param eval_every_episodes: evaluate every this many training episodes of 100 steps (the paper: 200)
    :param eval_episodes: episodes per evaluation (the paper: 3)
    :param address: Ray cluster to attach to (``ray.init(address=...)``); ``None``: a local Ray
        with this machine's cores (an already initialised Ray is used as it is)
    :param max_concurrent: at most this many trials at once (default: as many as free CPUs)
    :param max_failures: Ray restarts a failed trial from its checkpoint this many times
    :param wait: wait for another launcher running ``log_folder`` to end (default: refuse, naming it)
    :param storage: the grid's storage URI (``s3://...``, ``file://...``): the trials work in
        node-local folders and keep the grid there; ``log_folder`` is then only the launcher's (its lock)
    :raises ValueError: on a bad argument, before Ray starts; when another launcher runs ``log_folder``
    """
    trials = make_grid(grid, tuple(densities), seeds)
    check_budget(budget)
    check_number("eval_every_episodes", eval_every_episodes, 0, low_open=True, expected="a number of training episodes > 0")
    check_integer("eval_episodes", eval_episodes, 1)
    if max_concurrent is not None:
        check_integer("max_concurrent", max_concurrent, 1)
    log_folder = Path(log_folder).resolve()
    place = GridStorage(storage) if storage else None
    settings = {"budget": float(budget), "eval_every_episodes": eval_every_episodes, "eval_episodes": eval_episodes}
    check_settings(log_folder, settings, place)

    outcome = BenchmarkRun()
    todo = [spec for spec in trials if not _finished(log_folder, spec, place)]
    outcome.skipped = [spec.trial_id for spec in trials if spec not in todo]
    if verbose:
        print(
            f"Benchmark grid {grid!r}: {len(trials)} trials, {len(outcome.skipped)} finished before, {len(todo)} to run "
            f"(budget {budget:g} x 1M env steps, evaluation: {eval_episodes} episodes every {eval_every_episodes:g} "
            f"training episodes) in {storage or log_folder}"
        )
    if not todo:
        return outcome
    ray = _import_ray()
    with grid_lock(log_folder, wait):
        done = [spec for spec in todo if _finished(log_folder, spec, place)]  # by a launcher this one waited for
        if done:
            outcome.skipped += [spec.trial_id for spec in done]
            todo = [spec for spec in todo if spec not in done]
            if verbose:
                print(f"{len(done)} of them finished by the launcher this one waited for; {len(todo)} left to run")
            if not todo:
                return outcome
        launch = Launch(grid, log_folder, settings, address, max_concurrent, max_failures, verbose, place)
        return _run_waves(ray, launch, todo, outcome)


@contextmanager
def grid_lock(log_folder: Path, wait: bool = False) -> Iterator[None]:
    """Held while a launcher runs the grid in ``log_folder``: a second launcher on the same folder
    gets a ValueError naming the holder (host, process, start) or, with ``wait``, waits for it."""
    log_folder.mkdir(parents=True, exist_ok=True)
    lock = filelock.FileLock(str(log_folder / LOCK_FILE))
    try:
        lock.acquire(timeout=-1 if wait else 0)
    except filelock.Timeout:
        try:
            holder = read_json_object(log_folder / HOLDER_FILE)
        except (OSError, ValueError):
            holder = {}
        who = ", ".join(f"{key} {holder[key]}" for key in ("host", "pid", "started") if key in holder) or "holder unknown"
        raise ValueError(
            f"{log_folder} is being run by another launcher ({who}); wait for it to end (--wait), or use another --log-folder."
        ) from None
    try:
        holder = {"host": socket.gethostname(), "pid": os.getpid(), "started": time.strftime("%Y-%m-%dT%H:%M:%S")}
        write_text(log_folder / HOLDER_FILE, json.dumps(holder) + "\n")
        yield
    finally:
        (log_folder / HOLDER_FILE).unlink(missing_ok=True)
        lock.release()


@dataclass
class Launch:
    """What :func:`run_benchmark` hands to Ray: the grid, where it lives and how trials run."""

    grid: str
    log_folder: Path
    settings: dict[str, Any]
    address: str | None
    max_concurrent: int | None
    max_failures: int
    verbose: int
    storage: GridStorage | None


def _run_waves(ray: Any, launch: Launch, todo: list[TrialSpec], outcome: BenchmarkRun) -> BenchmarkRun:
    """Run ``todo`` on Ray (the launcher holding the folder's lock) and fill ``outcome``."""
    log_folder, place, settings = launch.log_folder, launch.storage, launch.settings
    todo = [spec for spec in todo if not _finished(log_folder, spec, place)]  # another launcher may have run some
    for spec in todo if place is None else []:  # a storage grid's trials check their checkpoint where they run
        line = repair_trial(log_folder, spec)
        if line is not None:  # said whatever the verbosity: files were moved
            outcome.repaired[spec.trial_id] = line
            print(line)
    if place is not None:
        place.write_text(SETTINGS_FILE, json.dumps(settings, indent=2) + "\n")
    else:
        write_text(log_folder / SETTINGS_FILE, json.dumps(settings, indent=2) + "\n")
    started_ray = _start_ray(ray, launch.address, launch.verbose)
    start = time.perf_counter()
    errors: dict[str, Any] = {}
    try:
        # a curriculum trial starts from another trial's final model: the trials run in waves, each
        # of those whose start has finished; a wave left unfinished (Ctrl-C) ends the run
        for wave in itertools.count():
            ready = [spec for spec in todo if spec.trial_id not in errors and _ready(log_folder, spec, place)]
            if not ready:
                break
            results = _tuner(launch, wave, ready).fit()
            errors.update({TrialSpec(**r.config["spec"]).trial_id: r.error for r in results if r.error is not None})
            if any(not _finished(log_folder, spec, place) and spec.trial_id not in errors for spec in ready):
                break
    finally:
        if started_ray:
            ray.shutdown()
    outcome.wall_time_s = time.perf_counter() - start
    for spec in todo:
        if _finished(log_folder, spec, place):
            outcome.completed.append(spec.trial_id)
        elif spec.trial_id in errors:
            outcome.failed[spec.trial_id] = failure_reason(errors[spec.trial_id])
        elif spec.starts_from is not None and spec.starts_from.trial_id in outcome.failed:
            outcome.failed[spec.trial_id] = f"not started: the trial it starts from ({spec.starts_from.trial_id}) failed"
        else:  # stopped before the end (Ctrl-C): continues from its checkpoint next time
            outcome.unfinished.append(spec.trial_id)
    return outcome


def failure_reason(error: BaseException) -> str:
    """A failed trial's error as one plain line: the trial's own exception (Ray wraps it in a
    ``RayTaskError`` whose text starts with coloured worker details), without terminal colours."""
    cause = getattr(error, "cause", None) or error
    lines = [line for line in str(cause).splitlines() if line.strip() and not line.lstrip().startswith("ray::")]
    text = lines[-1] if lines else ""
    return re.sub(r"\x1b\[[0-9;]*m", "", f"{type(cause).__name__}: {text}")


def _finished(log_folder: Path, spec: TrialSpec, storage: GridStorage | None = None) -> bool:
    """Whether the trial ``spec`` has finished in ``log_folder`` or in ``storage``: its ``result.json``,
    and every file it needs reads back (:func:`~sb3_marl.benchmark.repair.trial_damage`; a storage
    grid's trial checked on a temporary copy: the launcher's folder keeps none of the trials)."""
    if storage is not None:
        stamp = storage.stamp(f"trials/{spec.trial_id}/{RESULT}")
        if stamp is None:
            return False
        if storage.found_whole.get(spec.trial_id) != stamp:  # not checked since its result.json was written
            with tempfile.TemporaryDirectory(prefix="sb3-marl-check-") as copy:
                storage.download_trials(Path(copy), [spec.trial_id])
                if trial_damage(Path(copy), spec):
                    return False
            storage.found_whole[spec.trial_id] = stamp
        return True
    return (trial_folder(log_folder, spec) / RESULT).is_file() and not trial_damage(log_folder, spec)


def _ready(log_folder: Path, spec: TrialSpec, storage: GridStorage | None = None) -> bool:
    """Whether ``spec`` is to run now: unfinished, and it starts from no trial or from a finished one."""
    start = spec.starts_from
    return not _finished(log_folder, spec, storage) and (start is None or _finished(log_folder, start, storage))


def _import_ray() -> Any:
    """The ``ray`` module, or an error saying how to install it."""
    # short trials checkpoint often; Ray's advice to checkpoint less is noise here
    os.environ.setdefault("TUNE_WARN_EXCESSIVE_EXPERIMENT_CHECKPOINT_SYNC_THRESHOLD_S", "0")
    try:
        import ray
        import ray.tune
    except ImportError as error:
        raise ModuleNotFoundError(
            f"The benchmark runs on Ray Tune, which is not installed ({error}): pip install 'sb3-marl[ray]' (ray[tune] 2.60)."
        ) from None
    return ray


def _start_ray(ray: Any, address: str | None, verbose: int) -> bool:
    """Start (or attach to ``address``, else to ``RAY_ADDRESS``) Ray unless it runs already; returns
    whether it was started here. Without either, a new local cluster of this machine's cores, even
    where another one runs (``ray start``, another launcher): Ray would join that one otherwise."""
    started = not ray.is_initialized()
    if started:
        address = address or os.environ.get("RAY_ADDRESS") or None
        ray.init(
            address=address or "local",
            num_cpus=None if address else os.cpu_count(),
            include_dashboard=False,
            configure_logging=verbose > 0,
            log_to_driver=verbose > 1,
        )
    if verbose:
        cpus = ray.cluster_resources().get("CPU", 0)
        print(f"Ray cluster at {ray.get_runtime_context().gcs_address}: {cpus:g} CPUs, one per trial")
    return started


def _tuner(launch: Launch, wave: int, todo: list[TrialSpec]) -> Any:
    """Ray Tune's Tuner of the trials ``todo`` (``wave`` > 0: trials that start from the models of
    an earlier wave): one CPU each, Ray's state under ``<log_folder>/ray`` (or the storage's ``ray/``)."""
    from ray import tune

    place = launch.storage
    space = {"log_folder": str(launch.log_folder), "storage": place.uri if place else None, **launch.settings}
    return tune.Tuner(
        tune.with_resources(run_trial, {"cpu": 1}),
        param_space={"spec": tune.grid_search([spec.to_dict() for spec in todo]), **space},
        tune_config=tune.TuneConfig(
            max_concurrent_trials=launch.max_concurrent, trial_name_creator=_trial_id, trial_dirname_creator=_trial_id
        ),
        run_config=tune.RunConfig(
            name=f"{launch.grid}-{time.strftime('%Y%m%d-%H%M%S')}" + (f"-{wave + 1}" if wave else ""),
            storage_path=place.ray_path if place else str(launch.log_folder / "ray"),
            failure_config=tune.FailureConfig(max_failures=launch.max_failures),
            checkpoint_config=tune.CheckpointConfig(num_to_keep=1),
            verbose=min(launch.verbose, 1),
        ),
    )


@dataclass
class TrialStatus:
    """Where one trial of a grid stands in a log folder: ``finished`` (``result.json``, every file
    read back), ``unfinished`` (a checkpoint to continue from), ``not started``, or ``unreadable``
    (``problems``: each damaged file and why; the next run repairs it); AV-steps done of the
    budget's ``n_timesteps``; the final evaluation's mean return once finished; its training time
    over all attempts [s] (:func:`~sb3_marl.benchmark.trial_files.total_wall_time`)."""

    trial_id: str
    state: str
    timesteps: int
    n_timesteps: int
    return_mean: float | None = None
    wall_time_s: float | None = None
    problems: list[str] = field(default_factory=list)  # "<file>: <why>", one per damaged file


def grid_status(
    grid: str,
    log_folder: str | Path,
    seeds: int = GRID_SEEDS,
    densities: tuple[int, ...] = tuple(DENSITIES),
    checkpoints: bool = True,
) -> list[TrialStatus]:
    """Each trial of ``grid`` (as :func:`run_benchmark` would run it into ``log_folder``), in order;
    ``checkpoints`` False: of an unfinished trial's checkpoint only its ``state.json`` is read (a
    storage grid's local copy has no other checkpoint file).

    :raises FileNotFoundError: if ``log_folder`` holds no benchmark (no ``benchmark.json``)
    :raises ValueError: naming a bad grid, density or seed count
    """
    trials = make_grid(grid, tuple(densities), seeds)
    settings_path = Path(log_folder) / SETTINGS_FILE
    if not settings_path.is_file():
        raise FileNotFoundError(
            f"No benchmark in {log_folder}/ (no {SETTINGS_FILE}): start one there, e.g. a short one with "
            f"`sb3-marl benchmark --grid {grid} --budget 0.01 -f {log_folder}` (the committed full-budget grid is "
            "results/paper-grid)."
        )
    settings = read_json_object(settings_path)
    budget: Any = settings.get("budget")
    try:
        check_budget(budget)
    except ValueError:
        raise ValueError(f"{settings_path}: 'budget' is {budget!r}, expected a fraction in (0, 1].") from None
    return [_trial_status(Path(log_folder), spec, spec.n_timesteps(budget), checkpoints) for spec in trials]


def _trial_status(log_folder: Path, spec: TrialSpec, n_timesteps: int, checkpoints: bool) -> TrialStatus:
    """Where ``spec``'s trial stands in ``log_folder`` (see :func:`grid_status`)."""
    folder = trial_folder(log_folder, spec)
    status = TrialStatus(spec.trial_id, "not started", 0, n_timesteps)
    damage = trial_damage(log_folder, spec)
    finished = (folder / RESULT).is_file() and not damage
    if not finished and (folder / CHECKPOINT).is_dir():
        damage.update(checkpoint_damage(folder / CHECKPOINT, log_folder, whole=checkpoints))
    status.problems = [f"{path}: {why}" for path, why in damage.items()]
    if finished:
        result = read_json_object(folder / RESULT)
        final = checked_result(result)
        status.state, status.timesteps, status.wall_time_s = (
            "finished",
            int(result["num_timesteps"]),
            result.get("wall_time_s"),
        )
        status.return_mean = float(final["return_mean"])
    elif (folder / CHECKPOINT / "state.json").is_file() and folder / CHECKPOINT / "state.json" not in damage:
        status.state, status.timesteps = "unfinished", checkpoint_timesteps(folder / CHECKPOINT)
    if damage:
        status.state = "unreadable"
    if (folder / TRIAL).is_file() and folder / TRIAL not in damage:  # every attempt's (older results: the last one's)
        total = total_wall_time(read_trial_info(folder / TRIAL)["attempts"])
        status.wall_time_s = status.wall_time_s if total is None else total
    return status


def _trial_id(trial: Any) -> str:
    return TrialSpec(**trial.config["spec"]).trial_id


__all__ = ["SETTINGS_FILE", "BenchmarkRun", "TrialStatus", "check_settings", "grid_status", "run_benchmark"]
