"""The report's figures: learning curves, final returns, the comfort traces and the cooperative
lane change (episode replays of trained models)."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure  # no pyplot: no global backend, works headless and in notebooks
from matplotlib.patches import Patch

from sb3_marl.benchmark.grid import EXPERIMENTS
from sb3_marl.benchmark.statistics import TrialLog, select_trials
from sb3_marl.benchmark.tables import PAPER_ACCELERATION_STD, PAPER_FINDINGS, PAPER_RETURNS
from sb3_marl.common.files import save_figure, write_text
from sb3_marl.envs import DENSITIES
from sb3_marl.evaluation.plotting import with_default_style

#: Experiments whose learning curves also show the collision rate of the policy alone (the
#: periodic evaluations without the supervisor).
ALONE_CURVES = ("safety", "rule-prior")
ALONE_KEY = "supervisor_off_collision_rate"


@with_default_style
def plot_learning_curves(trials: list[TrialLog], out_dir: str | Path) -> list[Path]:
    """One ``learning_curves_<experiment>.png`` per experiment with data (see module doc); for
    :data:`ALONE_CURVES`, a second row with the collision rate of the policy alone."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for experiment, curves in EXPERIMENTS.items():
        densities = sorted({t.spec.density for t in trials if (t.spec.algo, t.spec.variant) in curves.values()})
        if not densities:
            continue
        rows = 2 if experiment in ALONE_CURVES else 1
        fig = Figure(figsize=(5 * len(densities), 4 * rows))
        axes = fig.subplots(rows, len(densities), squeeze=False)
        for column, density in enumerate(densities):
            ax = axes[0][column]
            for label, (algo, variant) in curves.items():
                selected = select_trials(trials, algo, variant, density)
                if not selected:
                    continue
                length = min(len(t.eval_returns()) for t in selected)
                x = selected[0].training_episodes()[:length]
                returns = np.stack([t.eval_returns()[:length] for t in selected])
                mean, std = returns.mean(axis=0), returns.std(axis=0)
                ax.plot(x, mean, label=f"{label} ({len(selected)} seeds)")
                ax.fill_between(x, mean - std, mean + std, alpha=0.25)
                if rows == 2 and all(len(t.evaluations.get(ALONE_KEY, ())) >= length for t in selected):
                    alone = np.stack([t.evaluations[ALONE_KEY][:length] for t in selected]).mean(axis=0)
                    axes[1][column].plot(x, alone, label=f"{label} ({len(selected)} seeds)")
            if rows == 2:
                axes[1][column].set_xlabel("training episodes")
                axes[1][column].set_ylabel("collision rate without the supervisor")
                axes[1][column].grid(alpha=0.3)
                axes[1][column].legend(fontsize=8)
            ax.set_title(f"density {density}")
            ax.set_xlabel("training episodes")
            ax.set_ylabel("evaluation episode return")
            ax.grid(alpha=0.3)
            ax.legend(fontsize=8)
        fig.suptitle(PAPER_FINDINGS[experiment][0])
        fig.tight_layout()
        path = out_dir / f"learning_curves_{experiment}.png"
        save_figure(fig, path)
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
        if any(summaries[algo, variant, d] for algo, variant in curves.values() for d in DENSITIES)
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
            for density in DENSITIES:
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
            for density in DENSITIES
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
    save_figure(fig, path)
    return path


def acceleration_traces(trial: TrialLog, log_folder: str | Path, seed: int) -> np.ndarray:
    """Accelerations [m/s²] of each AV (columns) at each step (rows) of one evaluation episode of the
    trial's final model, with the density's largest AV count and episode seed ``seed``."""
    from sb3_marl.algos.common.policies import model_policy
    from sb3_marl.envs import av_counts, make_scenario
    from sb3_marl.evaluation import run_episodes
    from sb3_marl.runs.folders import find_run

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
        label: {d: select_trials(finished, algo, variant, d) for d in DENSITIES}
        for label, (algo, variant) in EXPERIMENTS["comfort"].items()
    }
    densities = [d for d in DENSITIES if all(by_density[d] for by_density in curves.values())]
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
    save_figure(fig, path)
    return path


def plot_interpretation(trials: list[TrialLog], log_folder: str | Path, out_dir: str | Path, seed: int) -> list[Path]:
    """``cooperative_lane_change.json`` and, if an AV yielded, ``.png`` (see module doc); nothing
    without a finished MA2C trial at density 2 or 3."""
    from sb3_marl.algos.common.policies import model_policy
    from sb3_marl.benchmark.trial_files import FINAL_EVAL_EPISODES
    from sb3_marl.evaluation.interpretation import describe, find_cooperative_lane_change, plot_cooperative_lane_change
    from sb3_marl.runs.folders import find_run

    candidates = [t for density in (3, 2) for t in select_trials(trials, "ma2c", "default", density) if t.result is not None]
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
    write_text(path, json.dumps(summary, indent=2) + "\n")
    return [path, *written]
