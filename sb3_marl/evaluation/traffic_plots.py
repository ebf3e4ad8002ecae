"""Figures of the traffic view: time–space diagrams of episodes and the distributions of the
vehicles' closest encounters (minimum TTC and time headway) per policy."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure

from sb3_marl.common.files import save_figure
from sb3_marl.evaluation.plotting import with_default_style
from sb3_marl.evaluation.trips import section_end
from sb3_marl.sim import kernel

#: Width [m] of a lateral band of the time–space diagram (the lanes' width): one panel per band.
BAND = 4.0
#: Speeds [m/s] of the colour scale.
SPEED_RANGE = (0.0, 30.0)


class PositionTrace:
    """Every vehicle's position and speed on the road at each policy step of one episode: a step
    hook (``trace(env, info)``) or, like :class:`~sb3_marl.evaluation.trips.TripRecorder`, fed
    with ``start`` / ``step``; ``rows``: (time [s], id, x [m], y [m], speed [m/s], is AV)."""

    def __init__(self) -> None:
        self.samples: list[np.ndarray] = []
        self.time, self.dt, self.road_end, self.n_avs = 0.0, 0.0, 0.0, 0

    def __call__(self, env: Any, info: dict) -> None:
        if info["step"] == 0:
            self.start(env.state, env.n_avs, None, env.horizon, env.config)
        else:
            self.step(env.state)

    def start(self, state: np.ndarray, n_avs: int, seed: int | None, horizon: Any, config: dict[str, Any]) -> None:
        self.samples, self.time, self.n_avs = [], 0.0, n_avs
        self.dt, self.road_end = 1.0 / config["policy_frequency"], section_end(horizon)
        self._sample(state)

    def step(self, state: np.ndarray) -> None:
        self.time += self.dt
        self._sample(state)

    def _sample(self, state: np.ndarray) -> None:
        rows = state[(state[:, kernel.IS_OBSTACLE] == 0) & (state[:, kernel.X] <= self.road_end)]
        ids = rows[:, kernel.VEHICLE_ID]
        columns = (np.full(len(rows), self.time), ids, rows[:, kernel.X], rows[:, kernel.Y], rows[:, kernel.SPEED])
        self.samples.append(np.column_stack([*columns, ids < self.n_avs]))

    @property
    def rows(self) -> np.ndarray:
        return np.concatenate(self.samples) if self.samples else np.zeros((0, 6))


@with_default_style
def plot_time_space(traces: dict[str, PositionTrace], path: str | Path, title: str = "") -> Path:
    """One row of panels per policy (``traces``: label -> one episode), one panel per lateral band
    of :data:`BAND` m (a lane; the merge's ramp joins the top one): each vehicle's position against
    time, coloured by speed, the AVs' lines thick with a black edge."""
    rows = {label: trace.rows for label, trace in traces.items()}
    every = np.concatenate(list(rows.values()))
    bands = int(np.clip(np.floor((every[:, 3] + BAND / 2) / BAND), 0, None).max()) + 1 if len(every) else 1
    figure = Figure(figsize=(4.2 * bands, 3.2 * len(rows)), layout="constrained")
    axes = figure.subplots(len(rows), bands, squeeze=False, sharex=True, sharey=True)
    mappable = None
    for r, (label, data) in enumerate(rows.items()):
        band = np.clip(np.floor((data[:, 3] + BAND / 2) / BAND), 0, bands - 1).astype(int)
        for b in range(bands):
            ax = axes[r, b]
            for vid in np.unique(data[:, 1]):
                mine = (data[:, 1] == vid) & (band == b)
                if mine.sum() < 2:
                    continue
                t, x, v, av = data[mine, 0], data[mine, 2], data[mine, 4], bool(data[mine, 5][0])
                split = np.flatnonzero(np.diff(t) > 1.5 * (t[1] - t[0] if len(t) > 1 else 1)) + 1  # left and came back
                for part in np.split(np.arange(len(t)), split):
                    points = np.column_stack([t[part], x[part]])
                    if len(points) < 2:
                        continue
                    if av:
                        ax.plot(points[:, 0], points[:, 1], color="black", linewidth=3.2, zorder=2)
                    lines = LineCollection(list(np.stack([points[:-1], points[1:]], axis=1)), cmap="viridis", zorder=3)
                    lines.set_array(v[part][:-1])
                    lines.set_clim(*SPEED_RANGE)
                    lines.set_linewidth(2.0 if av else 1.0)
                    mappable = ax.add_collection(lines)
            ax.set_title(f"{label}: lane band {b}", fontsize=9)
            ax.autoscale()
            if r == len(rows) - 1:
                ax.set_xlabel("time [s]")
            if b == 0:
                ax.set_ylabel("position x [m]")
    if mappable is not None:
        figure.colorbar(mappable, ax=axes, label="speed [m/s]", shrink=0.8)
    if title:
        figure.suptitle(title + " (AVs: thick, black edge)", fontsize=10)
    return save_figure(figure, path)


@with_default_style
def plot_encounters(trips: dict[str, list[dict[str, Any]]], path: str | Path, title: str = "") -> Path:
    """Per policy (``trips``: label -> trip records), the distribution of each vehicle's minimum
    TTC and minimum time headway over its trip (histograms of the share of vehicles, 0–10 s)."""
    figure = Figure(figsize=(10, 3.6), layout="constrained")
    axes = figure.subplots(1, 2)
    bins = np.linspace(0, 10, 41)
    names = {"minTTC": "minimum TTC [s]", "minTimeHeadway": "minimum time headway [s]"}
    for ax, (column, name) in zip(axes, names.items(), strict=True):
        for label, records in trips.items():
            values = np.array([t[column] for t in records], dtype=float)
            share = np.histogram(np.clip(values[np.isfinite(values)], 0, 10), bins)[0] / max(len(values), 1)
            ax.stairs(share, bins, label=label)
        ax.set_xlabel(name + " (10: 10 or more)")
        ax.set_ylabel("share of vehicles")
    axes[0].legend(fontsize=8)
    if title:
        figure.suptitle(title, fontsize=10)
    return save_figure(figure, path)


def time_space_diagram(policy: Any, env_id: str, seed: int, config: dict[str, Any], path: str | Path, label: str) -> Path:
    """:func:`plot_time_space` of the episode ``seed`` (the first of an evaluation from ``seed``: its
    AV count the density's first): ``policy`` with the supervisor (the authors' protocol) above the
    all-human reference of the same episode."""
    from sb3_marl.envs import av_counts, make_scenario
    from sb3_marl.envs.config import with_supervisor
    from sb3_marl.evaluation.episodes import run_episodes
    from sb3_marl.evaluation.trips import human_reference

    policy_trace, human_trace = PositionTrace(), PositionTrace()
    env = make_scenario(env_id, with_supervisor({**config, "n_avs": av_counts(env_id, config)[0]}, "on"))
    run_episodes(env, policy, 1, seed, on_step=policy_trace)
    env.close()
    human_reference(env_id, 1, seed, config, also=(human_trace,))
    traces = {f"{label}, supervisor on": policy_trace, "all human (no AV)": human_trace}
    return plot_time_space(traces, path, f"{env_id}, episode seed {seed}")


__all__ = ["PositionTrace", "plot_encounters", "plot_time_space", "time_space_diagram"]
