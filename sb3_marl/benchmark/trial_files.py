"""A benchmark trial's folder as data: its layout (:mod:`~sb3_marl.benchmark.trial` writes it)
and the readers that check what it holds (``trial.json``, ``result.json``, the run's
``evaluations.npz``, the checkpoint's AV-steps), which the trial, the repairs, the status and the
report share."""

from __future__ import annotations

from numbers import Real
from pathlib import Path
from typing import Any

import numpy as np

from sb3_marl.benchmark.grid import TrialSpec
from sb3_marl.common.checks import is_integer
from sb3_marl.common.files import read_evaluations, read_json_object

RUN_ID = 1
CHECKPOINT = "checkpoint"
PREVIOUS_CHECKPOINT = f".{CHECKPOINT}.previous"
#: Benchmark settings every trial of a log folder shares (``benchmark.json``).
SETTINGS = ("budget", "eval_every_episodes", "eval_episodes")
RESULT = "result.json"
#: The paper's final evaluation of a trained model: 30 seeded episodes (seeds 10000..10029, the
#: same for every trial and for ``sb3-marl evaluate``), actions sampled, the trial's scenario.
FINAL_EVAL_EPISODES = 30
TRIAL = "trial.json"


def trial_folder(log_folder: str | Path, spec: TrialSpec) -> Path:
    return Path(log_folder) / "trials" / spec.trial_id


def checkpoint_timesteps(checkpoint: Path) -> int:
    """AV-steps the trial had trained when it wrote ``checkpoint`` (its ``state.json``); a ValueError
    naming the file if it is unreadable or its ``num_timesteps`` is not an integer >= 0."""
    path = checkpoint / "state.json"
    timesteps: Any = read_json_object(path).get("num_timesteps")
    if not is_integer(timesteps) or timesteps < 0:
        raise ValueError(f"{path}: 'num_timesteps' is {str(timesteps)[:40]!r}, expected an integer >= 0.")
    return int(timesteps)


def read_trial_info(path: Path) -> dict[str, Any]:
    """A ``trial.json``: its ``trial`` a trial of the grids (:class:`TrialSpec`) and its ``attempts``
    (absent in none the benchmark writes) a list of objects whose ``wall_time_s`` are seconds; a
    ValueError naming the file otherwise."""
    info = read_json_object(path)
    try:
        TrialSpec(**info["trial"])
    except (KeyError, TypeError, ValueError) as error:
        raise ValueError(f"{path}: 'trial' {type(error).__name__}: {error}") from None
    attempts = info.setdefault("attempts", [])
    if not isinstance(attempts, list) or not all(
        isinstance(a, dict) and (a.get("wall_time_s") is None or _real(a["wall_time_s"])) for a in attempts
    ):
        raise ValueError(
            f"{path}: 'attempts' is {str(attempts)[:80]!r}, expected a list of objects with 'wall_time_s' seconds."
        )
    return info


def total_wall_time(attempts: list[dict[str, Any]]) -> float | None:
    """A trial's training time over all its ``attempts`` (``trial.json``'s) [s], each to its latest
    checkpoint (a killed attempt's time after it is not known); None if no attempt recorded one."""
    times = [float(a["wall_time_s"]) for a in attempts if a.get("wall_time_s") is not None]
    return round(sum(times), 1) if times else None


def checked_evaluations(path: Path) -> dict[str, Any]:
    """The arrays of an ``evaluations.npz`` (:func:`~sb3_marl.common.files.read_evaluations`) with
    numeric ``timesteps`` (evaluations,) and ``results`` (evaluations, episodes); a ValueError naming
    the file otherwise."""
    evaluations = read_evaluations(path)
    timesteps, results = evaluations.get("timesteps"), evaluations.get("results")
    if (
        timesteps is None
        or results is None
        or timesteps.ndim != 1
        or results.ndim != 2
        or len(results) != len(timesteps)
        or not np.issubdtype(timesteps.dtype, np.number)
        or not np.issubdtype(results.dtype, np.number)
    ):
        raise ValueError(f"{path}: expected numeric 'timesteps' (evaluations,) and 'results' (evaluations, episodes)")
    return evaluations


#: The most episode returns a final evaluation may list (the paper's has 30).
MAX_EVALUATION_EPISODES = 100_000


def final_evaluation(result: dict[str, Any]) -> dict[str, Any]:
    """A finished trial's final evaluation: the paper's (30 seeded episodes of the trained model,
    ``paper_evaluation``) where ``result`` has it, else its last periodic evaluation."""
    return result.get("paper_evaluation") or result["final_evaluation"]


def checked_result(result: dict[str, Any]) -> dict[str, Any]:
    """A finished trial's ``result.json`` as data, checked where it is read: its ``num_timesteps``
    an integer, its ``wall_time_s`` seconds or absent, its final evaluation's (and its
    ``supervisor_off``'s) summary values numbers and its ``returns`` at most
    :data:`MAX_EVALUATION_EPISODES` numbers; a ValueError (KeyError when missing) otherwise.
    Returns the final evaluation (:func:`final_evaluation`)."""
    if not is_integer(result.get("num_timesteps")):
        raise ValueError(f"'num_timesteps' is {str(result.get('num_timesteps'))[:40]!r}, expected an integer")
    wall_time = result.get("wall_time_s")
    if wall_time is not None and not _real(wall_time):
        raise ValueError(f"'wall_time_s' is {str(wall_time)[:40]!r}, expected seconds")
    final = final_evaluation(result)
    for summary in (final, *([final["supervisor_off"]] if isinstance(final, dict) and "supervisor_off" in final else [])):
        if not isinstance(summary, dict):
            raise ValueError(f"the final evaluation is {str(summary)[:80]!r}, expected an object")
        numbers = {key: value for key, value in summary.items() if key.endswith(("_mean", "_std", "_rate", "_episode"))}
        returns = summary.get("returns", [])
        if not all(map(_real, numbers.values())) or not (
            isinstance(returns, list) and len(returns) <= MAX_EVALUATION_EPISODES and all(map(_real, returns))
        ):
            raise ValueError("the final evaluation's summary values and 'returns' must be numbers")
    return final


def _real(value: Any) -> bool:
    """A real number, NaN included (an evaluation's mean of nothing), not a bool."""
    return isinstance(value, Real) and not isinstance(value, bool)
