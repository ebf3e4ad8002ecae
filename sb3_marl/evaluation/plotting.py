"""Learning-curve PNGs of one or several runs in rl-zoo's log layout.

Training returns come from each run's ``monitor.csv`` through SB3's ``load_results`` / ``ts2xy`` /
``window_func`` (the helpers rl_zoo3's ``plot_train`` uses); evaluation return (mean ± std over
the evaluation episodes) and collision rate from ``evaluations.npz``.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import matplotlib.style
import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure  # no pyplot: no global backend, works headless and in notebooks
from stable_baselines3.common.monitor import LoadMonitorResultsError, load_results
from stable_baselines3.common.results_plotter import X_TIMESTEPS, ts2xy, window_func

from sb3_marl.common.files import read_evaluations, save_figure

#: file name -> (y label, what is plotted)
FIGURES = {
    "train_return.png": "Training episode return per AV (rolling mean)",
    "eval_return.png": "Evaluation episode return (mean ± std)",
    "collision_rate.png": "Evaluation collision rate",
}


F = TypeVar("F", bound=Callable[..., Any])


def with_default_style(function: F) -> F:
    """Draw with matplotlib's default style whatever style the caller (a notebook, seaborn) has
    set, so the same logs always give the same files."""

    @functools.wraps(function)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        with matplotlib.style.context("default"):
            return function(*args, **kwargs)

    return wrapper  # type: ignore[return-value]


@with_default_style
def plot_runs(runs: dict[str, Path], out_dir: str | Path, window: int = 100) -> list[Path]:
    """Write the :data:`FIGURES` for ``runs`` (label -> run folder) into ``out_dir``; returns the
    files written. Runs without the needed log file are left out of that figure; an unreadable
    ``evaluations.npz`` raises a ValueError naming it before any file is written."""
    evaluations = {
        folder: read_evaluations(Path(folder) / "evaluations.npz")
        for folder in runs.values()
        if (Path(folder) / "evaluations.npz").is_file()
    }
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for name, title in FIGURES.items():
        fig = Figure(figsize=(7, 4.5))
        ax = fig.subplots()
        plotted = 0
        for label, folder in runs.items():
            plotted += _plot_one(ax, name, label, Path(folder), window, evaluations.get(folder))
        if plotted:
            ax.set_title(title)
            ax.set_xlabel("Timesteps (AV-steps)")
            ax.set_ylabel(title.split(" (")[0])
            ax.grid(alpha=0.3)
            ax.legend(fontsize=8)
            fig.tight_layout()
            save_figure(fig, out_dir / name)
            written.append(out_dir / name)
    return written


def _plot_one(ax: Axes, figure: str, label: str, folder: Path, window: int, log: dict[str, Any] | None) -> int:
    """Plot one run's curve of ``figure`` (``log``: its evaluations); 1 if it had data, else 0.
    Where the run was evaluated without the safety supervisor too, that curve is drawn dashed."""
    if figure == "train_return.png":
        try:
            x, y = ts2xy(load_results(str(folder)), X_TIMESTEPS)
        except LoadMonitorResultsError:
            return 0
        if len(x) == 0:
            return 0
        if len(x) >= window:
            x, y = window_func(x, y, window, np.mean)
        ax.plot(x, y, label=label)
        return 1
    if log is None:
        return 0
    off = "supervisor_off_"
    alone = off + "results" in log and len(log[off + "results"]) == len(log["timesteps"])
    if figure == "eval_return.png":
        mean, std = log["results"].mean(axis=1), log["results"].std(axis=1)
        line = ax.plot(log["timesteps"], mean, marker="o", label=label + (", supervisor on" if alone else ""))[0]
        ax.fill_between(log["timesteps"], mean - std, mean + std, alpha=0.2)
        if alone:
            ax.plot(
                log["timesteps"],
                log[off + "results"].mean(axis=1),
                marker="x",
                linestyle="--",
                color=line.get_color(),
                label=label + ", supervisor off",
            )
    else:
        line = ax.plot(
            log["timesteps"], log["collision_rate"], marker="o", label=label + (", supervisor on" if alone else "")
        )[0]
        if alone:
            ax.plot(
                log["timesteps"],
                log[off + "collision_rate"],
                marker="x",
                linestyle="--",
                color=line.get_color(),
                label=label + ", supervisor off",
            )
        ax.set_ylim(-0.05, 1.05)
    return 1


__all__ = ["FIGURES", "plot_runs", "with_default_style"]
