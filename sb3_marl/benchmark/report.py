"""Aggregate a benchmark log folder into the paper's table and figures.

- ``paper_table.md``: per experiment, per curve and density, the final evaluation over seeds
  (the paper's: 30 seeded episodes of each trained model, :meth:`TrialLog.final`; mean ± std of
  the seeds' final evaluation returns; the interquartile mean of all the seeds' episode returns
  with a 95 % stratified-bootstrap confidence interval, :func:`iqm_with_ci`; collision rate, the
  return and collision rate of the policy alone (supervisor off, same episodes), lane changes and
  yields per episode, mean speed [m/s], acceleration std [m/s²] and supervisor intervention rate
  averaged over seeds) beside the paper's numbers and claims, each claim checked per density (returns
  by their IQM CIs, acceleration std by its range over seeds), and the hand-written reference
  policies (IDM/MOBIL, cruise, random) on the same episodes, with the learners against IDM/MOBIL;
- ``learning_curves_<experiment>.png``: evaluation return against training episodes, one panel
  per density, mean over seeds with a shaded ± std band (the layout of the paper's figures);
- ``final_returns.png``: the table's final returns at a glance: per experiment and density, each
  curve's IQM with its 95 % CI beside the paper's Table-5 numbers and IDM/MOBIL's;
- ``comfort.png``: AV acceleration traces of one evaluation episode with the comfort term on and
  off, and the acceleration std of the final evaluations;
- ``cooperative_lane_change.png`` / ``.json`` (the paper's experiment 6, policy interpretation):
  among the final evaluation episodes of the finished MA2C trials at densities 2 and 3, the
  lane change an AV yielded to with the largest speed drop (:mod:`sb3_marl.interpretation`),
  as road snapshots and speed traces; the json says which, or that no AV yielded.

Only finished trials (with ``result.json``) enter the table; curves also show unfinished ones.
Outputs of an earlier report that this one does not produce (a figure whose trials are gone) are
removed from the output folder, so it always shows one report; other files there are left alone.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure  # no pyplot: no global backend, works headless and in notebooks
from matplotlib.patches import Patch

from sb3_marl.benchmark.grid import EPISODE_STEPS, EXPERIMENTS, TrialSpec
from sb3_marl.benchmark.runner import SETTINGS_FILE
from sb3_marl.benchmark.trial import RESULT, TRIAL, final_evaluation
from sb3_marl.evaluation import PROTOCOLS
from sb3_marl.files import read_evaluations
from sb3_marl.plotting import with_default_style

#: Table 5 of the paper: mean evaluation episode reward ± std, per algorithm and density.
PAPER_RETURNS: dict[tuple[str, int], tuple[float, float]] = {
    ("madqn", 1): (47.45, 27.95),
    ("madqn", 2): (51.57, 32.94),
    ("madqn", 3): (48.51, 24.08),
    ("ma2c", 1): (58.00, 9.31),
    ("ma2c", 2): (44.74, 10.90),
    ("ma2c", 3): (32.58, 8.16),
    ("maacktr", 1): (8.81, 6.22),
    ("maacktr", 2): (3.76, 10.86),
    ("maacktr", 3): (4.89, 10.99),
    ("mappo", 1): (31.99, 6.57),
    ("mappo", 2): (19.30, 16.10),
    ("mappo", 3): (5.07, 19.76),
}
#: Std of AV acceleration [m/s²] with the comfort term on and off (the paper's experiment 3).
PAPER_ACCELERATION_STD = {"default": 0.455, "no-comfort": 0.582}
#: Experiment -> (paper section title, the paper's finding).
PAPER_FINDINGS = {
    "reward": ("Experiment 1: local vs global reward", "local reward: higher return and lower variance"),
    "sharing": ("Experiment 2: shared vs separate actor-critic", "shared network: higher return and lower variance"),
    "comfort": ("Experiment 3: comfort term on vs off", "acceleration std 0.455 m/s² (on) vs 0.582 m/s² (off)"),
    "politeness": ("Experiment 4: HDV politeness p=0 vs p=1", "stable performance under both"),
    "baselines": ("Experiment 5: baselines", "best mean return in its Table 5: MA2C at density 1, MADQN at densities 2 and 3"),
    "penalty": (
        "Beyond the paper: MA2C's intervention penalty on vs off",
        "not studied (the authors train on the paper's reward alone)",
    ),
    "safety": (
        "Beyond the paper: MA2C trained behind the supervisor (default) vs with safety training",
        "not studied (the authors train and evaluate behind the supervisor only)",
    ),
    "ctde": (
        "Beyond the paper: MA2C with a local critic vs a centralised critic (CTDE), separate networks both",
        "not studied (the paper's critics see one AV's view)",
    ),
}

#: Experiment -> what a reader must know to compare its curves' returns.
EXPERIMENT_NOTES = {
    "comfort": "With the comfort term off, the reward (training and evaluation) has no comfort penalty, so the "
    "comfort-off returns are not comparable with the comfort-on ones; compare the acceleration std.",
    "politeness": "With p = 1 the HDVs themselves drive differently (MOBIL weighs their neighbours' gain), so the "
    "scenario, not only the learner, differs between the curves.",
}

#: Driving metrics of the final evaluation, averaged over seeds in the table.
DRIVING_METRICS = ("collision_rate", "lane_changes_per_episode", "speed_mean", "acceleration_std", "intervention_rate")
#: Bootstrap resamples of the IQM's confidence interval (rliable's default).
BOOTSTRAP_REPS = 50_000
#: Names (glob patterns) of the files a report writes into its output folder.
REPORT_OUTPUTS = ("paper_table.md", "learning_curves_*.png", "final_returns.png", "comfort.png", "cooperative_lane_change.*")


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
    files cannot be read (truncated, edited) is left out, its file and error appended to ``problems``."""
    trials = []
    for info_path in sorted(Path(log_folder).glob(f"trials/*/{TRIAL}")):
        try:
            spec = TrialSpec(**json.loads(info_path.read_text())["trial"])
            npz = sorted(info_path.parent.glob(f"{spec.algo}/*_1/evaluations.npz"))
            if not npz:
                continue
            evaluations = read_evaluations(npz[0])
            result_path = info_path.parent / RESULT
            try:
                result = json.loads(result_path.read_text()) if result_path.is_file() else None
            except ValueError as error:
                raise ValueError(f"{result_path}: {error}") from None
        except (ValueError, KeyError, TypeError) as error:
            if problems is None:
                raise
            problems.append(f"{info_path.parent.name}: {error}")
            continue
        trials.append(TrialLog(spec, evaluations, result))
    return trials


def _select(trials: list[TrialLog], algo: str, variant: str, density: int) -> list[TrialLog]:
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
        (algo, variant, density): final_over_seeds(_select(trials, algo, variant, density))
        for curves in EXPERIMENTS.values()
        for algo, variant in curves.values()
        for density in (1, 2, 3)
    }


def reference_summaries(trials: list[TrialLog], log_folder: str | Path, seed: int) -> dict[tuple[str, int], dict[str, Any]]:
    """Each hand-written policy of :data:`sb3_marl.baselines.BASELINES`, keyed by (name, density), on
    the final evaluation's episodes (seeds ``seed ..``, the same AV counts) at each density with a
    finished default MA2C trial, in that trial's scenario config (the zoo's: safety supervisor on).

    The IQM's confidence interval resamples the 30 episodes (a fixed policy: its only randomness
    is the episodes'), where the learners' resamples seeds."""
    from sb3_marl.baselines import BASELINES
    from sb3_marl.benchmark.trial import FINAL_EVAL_EPISODES
    from sb3_marl.evaluation import protocol_records, summarize
    from sb3_marl.runs import find_run

    summaries = {}
    for density in (1, 2, 3):
        finished = [t for t in _select(trials, "ma2c", "default", density) if t.result is not None]
        if not finished:
            continue
        spec = finished[0].spec
        config = find_run(Path(log_folder) / "trials" / spec.trial_id, spec.algo, spec.env_id).env_config
        for name, policy_class in BASELINES.items():
            protocols = protocol_records(policy_class(), spec.env_id, FINAL_EVAL_EPISODES, seed, config)
            records = protocols["on"]
            summary = summarize(records)
            alone = summarize(protocols["off"])
            alone["return_std"] = 0.0  # a std over seeds: one fixed policy, like the learners' cells
            iqm, low, high = iqm_with_ci(np.array([[r.episode_return] for r in records]))
            summaries[name, density] = {**summary, "iqm": iqm, "iqm_low": low, "iqm_high": high, "supervisor_off": alone}
    return summaries


def paper_table(
    trials: list[TrialLog],
    settings: dict[str, Any] | None = None,
    references: dict[tuple[str, int], dict[str, Any]] | None = None,
    summaries: dict[tuple[str, str, int], dict[str, Any] | None] | None = None,
) -> str:
    """The markdown of ``paper_table.md`` (see module doc), with the hand-written policies'
    :func:`reference_summaries` after the paper's experiments if given; ``summaries``: the trials'
    :func:`curve_summaries` if already computed."""
    lines = ["# Paper reproduction: final evaluation over seeds", ""]
    if settings:
        lines += [
            f"Budget {settings['budget']:g} x the paper's 1M env steps per trial; evaluation: "
            f"{settings['eval_episodes']} episodes every {settings['eval_every_episodes']:g} training episodes "
            "(the paper: 3 every 200). Final evaluation: 30 seeded episodes of each trained model (trials "
            "from before it existed: their last periodic evaluation). "
            "Return: the seeds' final evaluation returns (mean ± std over seeds), and the interquartile "
            "mean (IQM) of all the seeds' episode returns with its 95 % confidence interval "
            f"(rliable's definitions: stratified percentile bootstrap over seeds, {BOOTSTRAP_REPS:,} resamples, "
            "seeded); the other columns: mean over seeds of the final evaluation. Supervisor interventions: "
            "share of AV-steps whose action the safety supervisor replaced.",
            "",
        ]
    lines += [
        f"Evaluation protocol: {PROTOCOLS[False]}; action masks for the learners that have them; the safety "
        "supervisor on (the authors' protocol) and, in the supervisor-off columns, off: the policy alone on the "
        "same episodes. Yields: lane changes an AV behind slowed down for (`EpisodeTrace.yields`).",
        "",
    ]
    finished = sum(t.result is not None for t in trials)
    lines += [f"Trials: {finished} finished, {len(trials) - finished} unfinished (not in the table).", ""]
    summaries = curve_summaries(trials) if summaries is None else summaries
    for experiment, curves in EXPERIMENTS.items():
        title, finding = PAPER_FINDINGS[experiment]
        rows = []
        for density in (1, 2, 3):
            for label, (algo, variant) in curves.items():
                summary = summaries[algo, variant, density]
                if summary is None:
                    continue
                paper = PAPER_RETURNS.get((algo, density)) if experiment == "baselines" else None
                paper_return = f"{paper[0]:.2f} ± {paper[1]:.2f}" if paper else "—"
                paper_accel = PAPER_ACCELERATION_STD.get(variant) if experiment == "comfort" else None
                rows.append(
                    f"| {label} | {density} | {summary['seeds']} | {summary['env_steps']:,} | "
                    f"{summary['return_mean']:.2f} ± {summary['return_std']:.2f} | {_iqm_cell(summary)} | {paper_return} | "
                    f"{summary['collision_rate']:.2f} | {_alone_cells(summary)} | {summary['lane_changes_per_episode']:.1f} | "
                    f"{_yields_cell(summary)} | {summary['speed_mean']:.2f} | {summary['acceleration_std']:.3f}"
                    + (f" (paper {paper_accel})" if paper_accel else "")
                    + f" | {summary['intervention_rate']:.3f} |"
                )
        if not rows:
            continue
        note = [EXPERIMENT_NOTES[experiment], ""] if experiment in EXPERIMENT_NOTES else []
        lines += [
            f"## {title}",
            "",
            f"The paper: {finding}.",
            "",
            *note,
            (
                "| curve | density | seeds | env steps | return: mean ± std over seeds | return: IQM [95 % CI] "
                "| return (paper) | collision rate | supervisor off: return | supervisor off: collision rate "
                "| lane changes / ep. | yields / ep. | mean speed [m/s] | accel. std [m/s²] | supervisor interventions |"
            ),
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
            *rows,
            "",
            *_findings(experiment, summaries),
            "",
        ]
    if references:
        lines += _reference_section(references, summaries)
    return "\n".join(lines)


def _alone_cells(summary: dict[str, Any]) -> str:
    """The two supervisor-off cells (return mean ± std, collision rate); dashes where not evaluated."""
    alone = summary.get("supervisor_off")
    if not alone:
        return "— | —"
    return f"{alone['return_mean']:.2f} ± {alone['return_std']:.2f} | {alone['collision_rate']:.2f}"


def _yields_cell(summary: dict[str, Any]) -> str:
    return f"{summary['yields_per_episode']:.2f}" if "yields_per_episode" in summary else "—"


def _iqm_cell(summary: dict[str, Any]) -> str:
    return f"{summary['iqm']:.2f} [{summary['iqm_low']:.2f}, {summary['iqm_high']:.2f}]" if "iqm" in summary else "—"


def _reference_section(
    references: dict[tuple[str, int], dict[str, Any]], summaries: dict[tuple[str, str, int], dict[str, Any] | None]
) -> list[str]:
    """The hand-written policies' rows (:func:`reference_summaries`) and, per density, the
    learners of experiment 5 against IDM/MOBIL."""
    rows = [
        f"| {name} | {density} | {s['episodes']} | {s['return_mean']:.2f} ± {s['return_std']:.2f} | "
        f"{_iqm_cell(s)} | {s['collision_rate']:.2f} | {s['supervisor_off']['return_mean']:.2f} | "
        f"{s['supervisor_off']['collision_rate']:.2f} | {s['lane_changes_per_episode']:.1f} | {_yields_cell(s)} | "
        f"{s['speed_mean']:.2f} | {s['acceleration_std']:.3f} | {s['intervention_rate']:.3f} |"
        for (name, density), s in sorted(references.items(), key=lambda item: item[0][1])
    ]
    lines = [
        "## Beyond the paper: hand-written reference policies",
        "",
        "Not learned (`sb3_marl/baselines.py`): IDM/MOBIL picks the meta-action a human driver of the scenario "
        "would; cruise always IDLE; random uniform. The same 30 episodes as the final evaluations, in the "
        "default MA2C trial's scenario config, with the safety supervisor and without it. Return: mean ± std "
        "over the episodes; the IQM's CI resamples episodes (the learners' resample seeds).",
        "",
        "| policy | density | episodes | return: mean ± std over episodes | return: IQM [95 % CI] | collision rate "
        "| supervisor off: return | supervisor off: collision rate | lane changes / ep. | yields / ep. "
        "| mean speed [m/s] | accel. std [m/s²] | supervisor interventions |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
        *rows,
        "",
    ]
    for density in (1, 2, 3):
        reference = references.get(("idm-mobil", density))
        learners: dict[str, dict[str, Any]] = {
            label: summary
            for label, (algo, variant) in EXPERIMENTS["baselines"].items()
            if (summary := summaries[algo, variant, density])
        }
        if reference is None or not learners:
            continue
        lines.append(
            f"- Here, density {density}: against IDM/MOBIL ({reference['iqm']:.2f}), "
            + ", ".join(f"{label} {s['iqm']:.2f} ({_ci_verdict(s, reference)})" for label, s in learners.items() if "iqm" in s)
            + "."
        )
        alone = {label: s["supervisor_off"] for label, s in learners.items() if s.get("supervisor_off")}
        if alone:
            idm = reference["supervisor_off"]
            lines.append(
                f"- Here, density {density}, the policy alone (supervisor off): IDM/MOBIL {idm['return_mean']:.2f} "
                f"(collision {idm['collision_rate']:.2f}); "
                + ", ".join(
                    f"{label} {a['return_mean']:.2f} (collision {a['collision_rate']:.2f})" for label, a in alone.items()
                )
                + "."
            )
    return [*lines, ""]


def _compare(a: float, b: float, above: str, below: str) -> str:
    return "the same" if np.isclose(a, b, rtol=0, atol=1e-9) else above if a > b else below


def _ci_verdict(a: dict[str, Any], b: dict[str, Any]) -> str:
    """Whether the IQMs' 95 % confidence intervals of ``a`` and ``b`` separate them."""
    if "iqm" not in a or "iqm" not in b:
        return "no IQM"
    if a["iqm_low"] > b["iqm_high"]:
        return "IQM higher, CIs disjoint"
    if a["iqm_high"] < b["iqm_low"]:
        return "IQM lower, CIs disjoint"
    return "IQM CIs overlap: not separated"


def _range_verdict(a: dict[str, Any], b: dict[str, Any], metric: str) -> str:
    """Whether the seeds' values of ``metric`` in ``a`` and ``b`` (their min..max ranges) separate them."""
    ranges = f"seeds {a[metric + '_min']:.3f}–{a[metric + '_max']:.3f} vs {b[metric + '_min']:.3f}–{b[metric + '_max']:.3f}"
    disjoint = a[metric + "_max"] < b[metric + "_min"] or b[metric + "_max"] < a[metric + "_min"]
    return f"{ranges}: {'every seed apart' if disjoint else 'ranges overlap, not separated'}"


def _findings(experiment: str, summaries: dict[tuple[str, str, int], dict[str, Any] | None]) -> list[str]:
    """Here, per density with every curve finished: the comparison the paper's finding makes, from
    the curves' :func:`final_over_seeds` summaries keyed by (algorithm, variant, density)."""
    curves = EXPERIMENTS[experiment]
    lines = []
    for density in (1, 2, 3):
        finals: dict[str, dict[str, Any]] = {
            label: summary for label, (algo, variant) in curves.items() if (summary := summaries[algo, variant, density])
        }
        if len(finals) < len(curves):
            continue
        (first, a), (second, b) = list(finals.items())[:2]
        if experiment in ("reward", "sharing", "penalty", "safety", "ctde"):
            finding = (
                f"{first} vs {second}: return {_compare(a['return_mean'], b['return_mean'], 'higher', 'lower')}"
                f" ({_ci_verdict(a, b)}), "
                f"std over seeds {_compare(a['return_std'], b['return_std'], 'higher', 'lower')}"
            )
        elif experiment == "comfort":
            finding = (
                f"acceleration std {a['acceleration_std']:.3f} m/s² ({first}) vs {b['acceleration_std']:.3f} m/s² "
                f"({second}): {_compare(a['acceleration_std'], b['acceleration_std'], 'higher', 'lower')} with comfort"
                f" ({_range_verdict(a, b, 'acceleration_std')})"
            )
        elif experiment == "politeness":
            gap = abs(a["return_mean"] - b["return_mean"])
            finding = (
                f"{first} vs {second}: returns differ by {gap:.2f}, "
                f"{'within' if gap <= max(a['return_std'], b['return_std']) else 'beyond'}"
                " the larger std over seeds"
                f" ({_ci_verdict(a, b)})"
            )
        else:
            best = max(finals, key=lambda label: finals[label]["return_mean"])
            others = [label for label in finals if label != best]
            finding = f"best final return: {best}; its IQM against " + ", ".join(
                f"{label}: {_ci_verdict(finals[best], finals[label])}" for label in others
            )
        if experiment in ("safety", "ctde") and a.get("supervisor_off") and b.get("supervisor_off"):
            off_a, off_b = a["supervisor_off"], b["supervisor_off"]
            finding += (
                f"; the policy alone (supervisor off): return {off_a['return_mean']:.2f} vs "
                f"{off_b['return_mean']:.2f}, collision rate {off_a['collision_rate']:.2f} vs "
                f"{off_b['collision_rate']:.2f}"
            )
        lines.append(f"- Here, density {density}: {finding}.")
    return lines


@with_default_style
def plot_learning_curves(trials: list[TrialLog], out_dir: str | Path) -> list[Path]:
    """One ``learning_curves_<experiment>.png`` per experiment with data (see module doc)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for experiment, curves in EXPERIMENTS.items():
        densities = sorted({t.spec.density for t in trials if (t.spec.algo, t.spec.variant) in curves.values()})
        if not densities:
            continue
        fig = Figure(figsize=(5 * len(densities), 4))
        axes = fig.subplots(1, len(densities), squeeze=False)
        for ax, density in zip(axes[0], densities):
            for label, (algo, variant) in curves.items():
                selected = _select(trials, algo, variant, density)
                if not selected:
                    continue
                length = min(len(t.eval_returns()) for t in selected)
                x = selected[0].training_episodes()[:length]
                returns = np.stack([t.eval_returns()[:length] for t in selected])
                mean, std = returns.mean(axis=0), returns.std(axis=0)
                ax.plot(x, mean, label=f"{label} ({len(selected)} seeds)")
                ax.fill_between(x, mean - std, mean + std, alpha=0.25)
            ax.set_title(f"density {density}")
            ax.set_xlabel("training episodes")
            ax.set_ylabel("evaluation episode return")
            ax.grid(alpha=0.3)
            ax.legend(fontsize=8)
        fig.suptitle(PAPER_FINDINGS[experiment][0])
        fig.tight_layout()
        path = out_dir / f"learning_curves_{experiment}.png"
        fig.savefig(path, dpi=100)
        written.append(path)
    return written


@with_default_style
def plot_final_returns(
    summaries: dict[tuple[str, str, int], dict[str, Any] | None],
    out_dir: str | Path,
    references: dict[tuple[str, int], dict[str, Any]] | None = None,
) -> Path | None:
    """``final_returns.png``: one panel per experiment with a finished trial; per density, each
    curve's IQM of the final evaluation returns with its 95 % CI as a bar and error bar, the
    paper's Table-5 mean (MA2C in every panel, the other baselines in theirs) as a black tick and,
    in the baselines' panel, IDM/MOBIL's IQM on the same episodes (``references``) as a grey line.
    None without a finished trial.

    :param summaries: the trials' :func:`curve_summaries`
    """
    experiments = [
        e
        for e, curves in EXPERIMENTS.items()
        if any(summaries[algo, variant, d] for algo, variant in curves.values() for d in (1, 2, 3))
    ]
    if not experiments:
        return None
    columns = min(3, len(experiments))
    rows = -(-len(experiments) // columns)
    fig = Figure(figsize=(5.5 * columns, 5 * rows))  # legends below the panels
    axes = fig.subplots(rows, columns, squeeze=False).ravel()
    for ax, experiment in zip(axes, experiments):
        curves = EXPERIMENTS[experiment]
        width = 0.8 / len(curves)
        legend: dict[str, Any] = {}
        for k, (label, (algo, variant)) in enumerate(curves.items()):
            x, iqm, low, high, paper = [], [], [], [], []
            for density in (1, 2, 3):
                summary = summaries[algo, variant, density]
                position = density + (k - (len(curves) - 1) / 2) * width
                if summary is not None and "iqm" in summary:
                    x.append(position)
                    iqm.append(summary["iqm"])
                    low.append(summary["iqm"] - summary["iqm_low"])
                    high.append(summary["iqm_high"] - summary["iqm"])
                if (algo, variant) in EXPERIMENTS["baselines"].values() and (algo, density) in PAPER_RETURNS:
                    paper.append((position, PAPER_RETURNS[algo, density][0]))
            ax.bar(x, iqm, width, yerr=[low, high], capsize=3, color=f"C{k}")
            legend[label if x else f"{label}: no finished trial"] = Patch(color=f"C{k}", alpha=1.0 if x else 0.3)
            if paper:
                legend["the paper (Table 5)"] = ax.plot(
                    *zip(*paper), linestyle="none", marker="_", markersize=14, markeredgewidth=2.5, color="black"
                )[0]
        idm_mobil = [
            (density, references["idm-mobil", density]["iqm"])
            for density in (1, 2, 3)
            if experiment == "baselines" and references and ("idm-mobil", density) in references
        ]
        if idm_mobil:
            legend["IDM/MOBIL, same episodes (IQM)"] = ax.hlines(
                [iqm for _, iqm in idm_mobil],
                [d - 0.45 for d, _ in idm_mobil],
                [d + 0.45 for d, _ in idm_mobil],
                colors="grey",
                linestyles="dashed",
            )
        if "the paper (Table 5)" in legend:  # after the curves
            legend["the paper (Table 5)"] = legend.pop("the paper (Table 5)")
        ax.legend(legend.values(), legend.keys(), fontsize=7, ncol=2, loc="upper center", bbox_to_anchor=(0.5, -0.1))
        ax.set_xticks([1, 2, 3], ["density 1", "density 2", "density 3"])
        ax.set_ylabel("final return: IQM [95 % CI]")
        ax.set_title(PAPER_FINDINGS[experiment][0], fontsize=10)
        ax.axhline(0, color="grey", linewidth=0.8)
        ax.grid(alpha=0.3, axis="y")
    for ax in axes[len(experiments) :]:
        ax.set_visible(False)
    fig.suptitle("Final evaluation (30 seeded episodes per trial, all seeds): IQM with 95 % bootstrap CI")
    fig.tight_layout()
    path = Path(out_dir) / "final_returns.png"
    fig.savefig(path, dpi=100)
    return path


def acceleration_traces(trial: TrialLog, log_folder: str | Path, seed: int) -> np.ndarray:
    """Accelerations [m/s²] of each AV (columns) at each step (rows) of one evaluation episode of the
    trial's final model, with the density's largest AV count and episode seed ``seed``."""
    from sb3_marl.envs import av_counts, make_scenario
    from sb3_marl.evaluation import model_policy, run_episodes
    from sb3_marl.runs import find_run

    run = find_run(Path(log_folder) / "trials" / trial.spec.trial_id, trial.spec.algo, trial.spec.env_id)
    policy = model_policy(run.load_model("cpu"))
    n_avs = max(av_counts(trial.spec.env_id, run.env_config))
    env = make_scenario(trial.spec.env_id, {**run.env_config, "n_avs": n_avs})
    accelerations: list[np.ndarray] = []

    def record(env: Any, info: dict) -> None:
        if info["step"] > 0:
            accelerations.append(np.asarray(info["acceleration"], dtype=float))

    run_episodes(env, policy, 1, seed, on_step=record)
    env.close()
    return np.array(accelerations)


@with_default_style
def plot_comfort(trials: list[TrialLog], log_folder: str | Path, out_dir: str | Path, seed: int) -> Path | None:
    """``comfort.png`` (see module doc); None without finished comfort-on and comfort-off trials."""
    finished = [t for t in trials if t.result is not None]
    curves = {
        label: {d: _select(finished, algo, variant, d) for d in (1, 2, 3)}
        for label, (algo, variant) in EXPERIMENTS["comfort"].items()
    }
    densities = [d for d in (1, 2, 3) if all(by_density[d] for by_density in curves.values())]
    if not densities:
        return None
    density = densities[0]
    fig = Figure(figsize=(15, 4))
    axes = fig.subplots(1, 3)
    for ax, (label, by_density) in zip(axes[:2], curves.items()):
        selected = by_density[density]
        trace = acceleration_traces(selected[0], log_folder, seed)
        time_s = np.arange(1, len(trace) + 1) / 5.0  # policy steps at 5 Hz
        for av in range(trace.shape[1]):
            ax.plot(time_s, trace[:, av], label=f"AV {av + 1}")
        ax.set_title(f"{label}: density {density}, seed {selected[0].spec.seed}, episode seed {seed}")
        ax.set_xlabel("time [s]")
        ax.set_ylabel("acceleration [m/s²]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    ax = axes[2]
    width = 0.35
    for k, (label, by_density) in enumerate(curves.items()):
        stds = [[t.final()["acceleration_std"] for t in by_density[d]] for d in densities]
        variant = EXPERIMENTS["comfort"][label][1]
        ax.bar(
            np.arange(len(densities)) + (k - 0.5) * width,
            [np.mean(s) for s in stds],
            width,
            yerr=[np.std(s) for s in stds],
            capsize=4,
            label=f"{label} (paper {PAPER_ACCELERATION_STD[variant]} m/s²)",
        )
    ax.set_xticks(np.arange(len(densities)), [f"density {d}" for d in densities])
    ax.set_ylabel("std of AV acceleration [m/s²]")
    ax.set_title("Final evaluation: acceleration std (seeds: mean ± std)", fontsize=10)
    ax.legend(fontsize=8)
    fig.tight_layout()
    path = Path(out_dir) / "comfort.png"
    fig.savefig(path, dpi=100)
    return path


def write_report(log_folder: str | Path, out_dir: str | Path = "results", seed: int = 10_000) -> list[Path]:
    """Write ``paper_table.md``, the learning curves and the comfort figure of ``log_folder`` into
    ``out_dir``; returns the files written.

    :raises FileNotFoundError: if ``log_folder`` has no evaluated trial
    """
    problems: list[str] = []
    trials = load_trials(log_folder, problems)
    for problem in problems:
        print(f"left out of the report (unreadable): {problem}")
    if not trials:
        raise FileNotFoundError(
            f"No evaluated benchmark trial under {Path(log_folder) / 'trials'}/ "
            "(run `sb3-marl benchmark` with this --log-folder first)."
        )
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    settings_path = Path(log_folder) / SETTINGS_FILE
    settings = json.loads(settings_path.read_text()) if settings_path.is_file() else None
    table = out_dir / "paper_table.md"
    references = reference_summaries(trials, log_folder, seed)
    summaries = curve_summaries(trials)
    table.write_text(paper_table(trials, settings, references, summaries))
    written = [table, *plot_learning_curves(trials, out_dir)]
    for figure in (plot_final_returns(summaries, out_dir, references), plot_comfort(trials, log_folder, out_dir, seed)):
        if figure is not None:
            written.append(figure)
    written += plot_interpretation(trials, log_folder, out_dir, seed)
    _remove_stale_outputs(out_dir, written)
    return written


def _remove_stale_outputs(out_dir: Path, written: list[Path]) -> None:
    """Delete the report outputs in ``out_dir`` (:data:`REPORT_OUTPUTS`) that were not ``written`` now."""
    for pattern in REPORT_OUTPUTS:
        for path in out_dir.glob(pattern):
            if path not in written:
                path.unlink()


def plot_interpretation(trials: list[TrialLog], log_folder: str | Path, out_dir: str | Path, seed: int) -> list[Path]:
    """``cooperative_lane_change.json`` and, if an AV yielded, ``.png`` (see module doc); nothing
    without a finished MA2C trial at density 2 or 3."""
    from sb3_marl.benchmark.trial import FINAL_EVAL_EPISODES
    from sb3_marl.evaluation import model_policy
    from sb3_marl.interpretation import describe, find_cooperative_lane_change, plot_cooperative_lane_change
    from sb3_marl.runs import find_run

    candidates = [t for density in (3, 2) for t in _select(trials, "ma2c", "default", density) if t.result is not None]
    if not candidates:
        return []
    searched, best = {}, None
    for trial in candidates:
        run = find_run(Path(log_folder) / "trials" / trial.spec.trial_id, "ma2c", trial.spec.env_id)
        policy = model_policy(run.load_model("cpu"))
        event, count = find_cooperative_lane_change(policy, trial.spec.env_id, FINAL_EVAL_EPISODES, seed, run.env_config)
        searched[trial.spec.trial_id] = describe(event, count)
        if event is not None and (best is None or event.speed_drop > best[1].speed_drop):
            best = (trial, event, policy, run.env_config)
    out_dir = Path(out_dir)
    summary: dict[str, Any] = {
        "episodes": f"the final evaluation's {FINAL_EVAL_EPISODES} episodes per trial, seeds {seed}..",
        "trials": searched,
        "figure": None,
        "finding": "no AV yielded to another's lane change in these episodes"
        if best is None
        else "the yield with the largest speed drop is drawn in cooperative_lane_change.png",
    }
    written = []
    if best is not None:
        trial, event, policy, config = best
        summary["figure"] = {"trial": trial.spec.trial_id, **asdict(event)}
        written.append(
            plot_cooperative_lane_change(
                policy,
                trial.spec.env_id,
                event,
                out_dir / "cooperative_lane_change.png",
                config,
                title=f"Cooperative lane change by MA2C ({trial.spec.trial_id}): episode seed {event.episode_seed}, "
                f"{event.n_avs} AVs",
            )
        )
    path = out_dir / "cooperative_lane_change.json"
    path.write_text(json.dumps(summary, indent=2) + "\n")
    return [path, *written]


__all__ = ["PAPER_ACCELERATION_STD", "PAPER_RETURNS", "TrialLog", "load_trials", "paper_table", "write_report"]
