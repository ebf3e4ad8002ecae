"""Benchmark statistics: the trials' logs, interquartile means with stratified-bootstrap CIs,
the final evaluation over seeds of every curve, and the hand-written reference policies' summaries."""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sb3_marl.benchmark.grid import EPISODE_STEPS, EXPERIMENTS, TrialSpec
from sb3_marl.benchmark.trial_files import RESULT, TRIAL, checked_evaluations, final_evaluation, read_trial_info
from sb3_marl.common.files import inside, read_json_object
from sb3_marl.envs import DENSITIES

#: Driving metrics of the final evaluation, averaged over seeds in the table.
DRIVING_METRICS = ("collision_rate", "lane_changes_per_episode", "speed_mean", "acceleration_std", "intervention_rate")
#: Bootstrap resamples of the IQM's confidence interval (rliable's default).
BOOTSTRAP_REPS = 50_000


@dataclass
class TrialLog:
    """A trial's logs: its evaluations (``evaluations.npz`` arrays) and its result if finished."""

    spec: TrialSpec
    evaluations: dict[str, np.ndarray]
    result: dict[str, Any] | None

    def training_episodes(self) -> np.ndarray:
        """Evaluation points in training episodes of 100 steps (env steps / 100)."""
        return self.spec.env_steps(self.evaluations["timesteps"]) / EPISODE_STEPS

    def eval_returns(self) -> np.ndarray:
        """Mean return of each evaluation."""
        return self.evaluations["results"].mean(axis=1)

    def final(self) -> dict[str, Any]:
        """The finished trial's final evaluation: the paper's (30 seeded episodes of the trained
        model, ``paper_evaluation``) where the trial has it, else its last periodic evaluation."""
        assert self.result is not None, f"{self.spec.trial_id} has not finished"
        return final_evaluation(self.result)


def load_trials(log_folder: str | Path, problems: list[str] | None = None) -> list[TrialLog]:
    """Every trial under ``<log_folder>/trials/`` that has evaluated at least once. A trial whose
    files cannot be read (truncated, edited: :func:`~sb3_marl.benchmark.repair.trial_damage`) is
    left out, each damaged file and its error appended to ``problems`` (raised without it), and so
    is a trial folder without ``trial.json`` or not evaluated yet, saying so."""
    from sb3_marl.benchmark.repair import trial_damage

    trials = []
    for folder in sorted(path for path in Path(log_folder).glob("trials/*") if path.is_dir()):
        try:
            spec = TrialSpec(**read_trial_info(inside(folder / TRIAL, log_folder))["trial"])
            if spec.trial_id != folder.name:
                raise ValueError(f"{folder / TRIAL} names the trial {spec.trial_id}, not {folder.name}")
            damage = trial_damage(Path(log_folder), spec)
            if damage:
                raise ValueError("; ".join(f"{path}: {why}" for path, why in damage.items()))
            npz = sorted(folder.glob(f"{spec.algo}/*_1/evaluations.npz"))
            if not npz:
                if problems is not None:
                    problems.append(f"{folder.name}: not evaluated yet (no {spec.algo}/*_1/evaluations.npz)")
                continue
            evaluations = checked_evaluations(npz[0])
            result = read_json_object(folder / RESULT) if (folder / RESULT).is_file() else None
        except (ValueError, KeyError, TypeError) as error:
            if problems is None:
                raise
            problems.append(f"{folder.name}: {error}")
            continue
        trials.append(TrialLog(spec, evaluations, result))
    return trials


def select_trials(trials: list[TrialLog], algo: str, variant: str, density: int) -> list[TrialLog]:
    return sorted(
        (t for t in trials if (t.spec.algo, t.spec.variant, t.spec.density) == (algo, variant, density)),
        key=lambda t: t.spec.seed,
    )


def interquartile_mean(scores: np.ndarray, axis: int | None = None) -> np.ndarray:
    """rliable's IQM: the mean of the middle 50 % of ``scores`` (``scipy.stats.trim_mean`` with
    0.25 cut from each end, ``int(0.25 n)`` values each side), over ``axis`` (None: all values)."""
    scores = np.asarray(scores, dtype=float)
    if axis is None:
        scores, axis = scores.reshape(-1), 0
    n = scores.shape[axis]
    cut = int(0.25 * n)
    return np.sort(scores, axis=axis).take(np.arange(cut, n - cut), axis=axis).mean(axis=axis)


def iqm_with_ci(
    scores: np.ndarray, reps: int = BOOTSTRAP_REPS, confidence: float = 0.95, seed: int = 0
) -> tuple[float, float, float]:
    """IQM of a (runs, tasks) score matrix and its percentile confidence interval by rliable's
    stratified bootstrap (runs resampled with replacement independently within each task).

    Here runs are a curve's seeds and tasks the 30 seeded evaluation episodes that every seed plays.
    Seeded, so the same scores give the same interval. (rliable itself is not a dependency: its
    pinned ``arch<8`` fails to import under pandas 3.)
    """
    scores = np.asarray(scores, dtype=float)
    runs, tasks = scores.shape
    rows = np.random.default_rng(seed).integers(0, runs, size=(reps, runs, tasks))
    resampled = np.take_along_axis(np.broadcast_to(scores, (reps, runs, tasks)), rows, axis=1)
    estimates = interquartile_mean(resampled.reshape(reps, -1), axis=1)
    tail = 100 * (1 - confidence) / 2
    low, high = np.percentile(estimates, [tail, 100 - tail])
    return float(interquartile_mean(scores)), float(low), float(high)


def final_over_seeds(trials: list[TrialLog]) -> dict[str, Any] | None:
    """Mean ± std over seeds of the finished trials' final evaluation return, the IQM of their
    episode returns with its 95 % CI (where every seed has the paper's final evaluation), and the
    seed means of the driving metrics; None without a finished trial."""
    finished = [t for t in trials if t.result is not None]
    if not finished:
        return None
    finals = [t.final() for t in finished]
    returns = np.array([f["return_mean"] for f in finals])
    summary: dict[str, Any] = {"seeds": len(finals), "return_mean": float(returns.mean()), "return_std": float(returns.std())}
    if all("returns" in f for f in finals) and len({len(f["returns"]) for f in finals}) == 1:
        iqm, low, high = iqm_with_ci(np.array([f["returns"] for f in finals]))
        summary.update(iqm=iqm, iqm_low=low, iqm_high=high)
    for metric in DRIVING_METRICS:
        summary[metric] = float(np.mean([f[metric] for f in finals]))
    accelerations = [f["acceleration_std"] for f in finals]
    summary.update(acceleration_std_min=float(min(accelerations)), acceleration_std_max=float(max(accelerations)))
    summary["env_steps"] = int(np.mean([t.result["env_steps"] for t in finished if t.result is not None]))
    alone: list[dict[str, Any]] = [f["supervisor_off"] for f in finals if f.get("supervisor_off")]
    if len(alone) == len(finals):  # the policy alone, where every seed was evaluated without the supervisor
        returns = np.array([a["return_mean"] for a in alone])
        summary["supervisor_off"] = {
            "return_mean": float(returns.mean()),
            "return_std": float(returns.std()),
            **{metric: float(np.mean([a[metric] for a in alone])) for metric in ("collision_rate", "yields_per_episode")},
        }
        summary["yields_per_episode"] = float(np.mean([f["yields_per_episode"] for f in finals]))
    return summary


def curve_summaries(trials: list[TrialLog]) -> dict[tuple[str, str, int], dict[str, Any] | None]:
    """:func:`final_over_seeds` of every (algorithm, variant, density) of the experiments, each once
    (the default MA2C curve appears in every experiment)."""
    return {
        (algo, variant, density): final_over_seeds(select_trials(trials, algo, variant, density))
        for curves in EXPERIMENTS.values()
        for algo, variant in curves.values()
        for density in DENSITIES
    }


#: Each road's reference MA2C variant and the suffix of its keys in :func:`reference_summaries`.
REFERENCE_VARIANTS = {"lane-change": ("default", ""), "merge": ("merge", ", merge")}


def reference_configs(trials: list[TrialLog], log_folder: str | Path) -> Iterator[tuple[str, int, str, dict[str, Any]]]:
    """(road, density, scenario id, scenario config) of each road of :data:`REFERENCE_VARIANTS` and
    density with a finished MA2C trial of the road's variant (the config of its first such trial,
    under the safety supervisor version its final evaluation was made with, so the references meet
    the learners' supervisor)."""
    from sb3_marl.runs.folders import find_run

    for (road, (variant, _)), density in itertools.product(REFERENCE_VARIANTS.items(), DENSITIES):
        finished = [t for t in select_trials(trials, "ma2c", variant, density) if t.result is not None]
        if finished:
            spec = finished[0].spec
            config = find_run(Path(log_folder) / "trials" / spec.trial_id, spec.algo, spec.env_id).env_config
            version = ((finished[0].result or {}).get("paper_evaluation") or {}).get("supervisor_version")
            yield road, density, spec.env_id, config if version is None else {**config, "supervisor_version": version}


def reference_summaries(trials: list[TrialLog], log_folder: str | Path, seed: int) -> dict[tuple[str, int], dict[str, Any]]:
    """Each hand-written policy of :data:`sb3_marl.evaluation.baselines.BASELINES`, keyed by (name, density), on
    the final evaluation's episodes (seeds ``seed ..``, the same AV counts) at each density with a
    finished default MA2C trial, in that trial's scenario config (the zoo's: safety supervisor on),
    with the traffic metrics of each protocol (``traffic``); on the merge (keyed by ``"<name>, merge"``)
    where a ``merge`` MA2C trial has finished (:func:`reference_configs`).

    The IQM's confidence interval resamples the 30 episodes (a fixed policy: its only randomness
    is the episodes'), where the learners' resamples seeds."""
    from sb3_marl.benchmark.trial_files import FINAL_EVAL_EPISODES
    from sb3_marl.evaluation import evaluate_protocols
    from sb3_marl.evaluation.baselines import BASELINES

    summaries = {}
    for road, density, env_id, config in reference_configs(trials, log_folder):
        suffix = REFERENCE_VARIANTS[road][1]
        for name, policy_class in BASELINES.items():
            summary = evaluate_protocols(policy_class(), env_id, FINAL_EVAL_EPISODES, seed, config, traffic=True)
            alone = summary.pop("supervisor_off")
            returns = summary.pop("returns")
            for protocol in (summary, alone):
                del protocol["trips"]
            del alone["returns"]
            alone["return_std"] = 0.0  # a std over seeds: one fixed policy, like the learners' cells
            iqm, low, high = iqm_with_ci(np.array([[r] for r in returns]))
            summaries[name + suffix, density] = {
                **summary,
                "iqm": iqm,
                "iqm_low": low,
                "iqm_high": high,
                "supervisor_off": alone,
            }
    return summaries


def clopper_pearson_upper(events: int, trials: int, confidence: float = 0.95) -> float:
    """Upper end of the two-sided Clopper–Pearson ``confidence`` interval of a rate observed as
    ``events`` in ``trials`` (e.g. crashes in episodes): the p at which P(X <= events) under
    Binomial(trials, p) is (1 - confidence) / 2; 1 when every trial was an event."""
    if not 0 <= events <= trials or trials < 1:
        raise ValueError(f"Invalid events={events}, trials={trials}: expected 0 <= events <= trials and trials >= 1.")
    if events == trials:
        return 1.0
    tail = (1 - confidence) / 2

    def cdf(p: float) -> float:
        return sum(
            math.exp(
                math.lgamma(trials + 1)
                - math.lgamma(i + 1)
                - math.lgamma(trials - i + 1)
                + i * math.log(p)
                + (trials - i) * math.log1p(-p)
            )
            for i in range(events + 1)
        )

    low, high = events / trials, 1.0
    for _ in range(100):  # cdf falls as p rises: bisect for cdf(p) = tail
        middle = (low + high) / 2
        low, high = (middle, high) if cdf(middle) > tail else (low, middle)
    return high
