"""The generalisation matrix: trained agents of a grid (:mod:`~sb3_marl.benchmark.trained_agents`)
evaluated off the conditions they were trained on — every scenario id (the other densities, the
other road), the HDVs' MOBIL politeness 0, 0.5 and 1 (0 in training) and their IDM style, timid
and aggressive (normal in training; ``sim.HDV_STYLES``) — on the same held-out
episodes, under both supervisor protocols; one row per (agent, training scenario), one column per
(evaluated scenario, politeness)."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle
from tqdm import tqdm

from sb3_marl.algos.common.policies import model_policy
from sb3_marl.benchmark.trained_agents import trained_agent
from sb3_marl.common.files import save_figure
from sb3_marl.envs import SCENARIO_IDS, scenario_of
from sb3_marl.envs.config import scenario_default_config
from sb3_marl.evaluation import evaluate_protocols
from sb3_marl.evaluation.plotting import with_default_style
from sb3_marl.runs.folders import find_run

#: The HDVs' MOBIL politeness of the evaluated conditions (the scenarios' default, and training's, is 0).
POLITENESS = (0.0, 0.5, 1.0)
#: The first held-out episode seed (never used in training or in the grid's evaluations).
HELD_OUT_SEED = 100_000


#: The HDVs' IDM styles of the evaluated conditions besides training's ``normal`` (sim.HDV_STYLES).
STYLES = ("timid", "aggressive")


@dataclass(frozen=True)
class Condition:
    """An evaluated condition: a scenario id, the HDVs' politeness and their IDM style."""

    env_id: str
    politeness: float
    style: str = "normal"

    @property
    def label(self) -> str:
        road = self.env_id.split("/")[-1].removesuffix("-v0")
        return f"{road}, p={self.politeness:g}" if self.style == "normal" else f"{road}, {self.style}"


def conditions(politeness: Iterable[float] = POLITENESS, styles: Iterable[str] = STYLES) -> list[Condition]:
    """Per scenario id: each politeness with normal HDVs, then each other style at politeness 0."""
    return [
        condition
        for env_id in SCENARIO_IDS
        for condition in [
            *(Condition(env_id, p) for p in politeness),
            *(Condition(env_id, 0.0, style) for style in styles if style != "normal"),
        ]
    ]


def generalisation_matrix(
    grid: str | Path,
    algo: str,
    names: list[str],
    seeds: int,
    episodes: int,
    politeness: Iterable[float] = POLITENESS,
    seed: int = HELD_OUT_SEED,
    progress: bool = True,
    styles: Iterable[str] = STYLES,
) -> dict[str, Any]:
    """Every agent ``names`` of ``algo`` in ``grid`` trained on any scenario id (training seeds
    ``0 .. seeds-1``), evaluated on :func:`conditions` for ``episodes`` episodes from ``seed`` per
    training seed: per cell the return with the supervisor (mean over seeds) and the pooled
    collision rate without it, with the episode count.

    :raises FileNotFoundError: when no agent of ``names`` exists
    """
    evaluated = conditions(politeness, styles)
    agents = []
    for name in names:
        for env_id in SCENARIO_IDS:
            try:
                agents.append((name, env_id, [trained_agent(grid, algo, env_id, name, s) for s in range(seeds)]))
            except FileNotFoundError:
                continue  # no such agent trained on that scenario (e.g. `safe` on the merge)
    if not agents:
        raise FileNotFoundError(f"no trained agent {names} of {algo} with {seeds} seed(s) in {grid}")
    rows = []
    jobs = tqdm(total=len(agents) * len(evaluated) * seeds, desc="generalisation", unit="evaluation", disable=not progress)
    for name, trained_env, folders in agents:
        runs = [find_run(folder, algo, trained_env) for folder in folders]
        policies = [(model_policy(run.load_model("cpu")), run.env_config) for run in runs]
        cells = {}
        for condition in evaluated:
            results = []
            for policy, env_config in policies:
                common = scenario_default_config(scenario_of(condition.env_id))
                hdvs = {"hdv_politeness": condition.politeness, "hdv_style": condition.style}
                config = {**{k: v for k, v in env_config.items() if k in common}, **hdvs}
                results.append(evaluate_protocols(policy, condition.env_id, episodes, seed, config))
                jobs.update()
            alone = [r["supervisor_off"] for r in results]
            cells[condition.label] = {
                "return_mean": float(np.mean([r["return_mean"] for r in results])),
                "collision_rate_alone": float(np.mean([r["collision_rate"] for r in alone])),
                "episodes": sum(r["episodes"] for r in results),
            }
        rows.append({"name": name, "trained_env": trained_env, "cells": cells})
    jobs.close()
    return {
        "algo": algo,
        "seeds": seeds,
        "episodes_per_seed": episodes,
        "episode_seeds": [seed, seed + episodes - 1],
        "conditions": [c.label for c in evaluated],
        "rows": rows,
    }


def matrix_table(result: dict[str, Any], key: str, spec: str) -> str:
    """A markdown table of one cell value (``key``) of :func:`generalisation_matrix`'s result."""
    lines = ["| trained on | " + " | ".join(result["conditions"]) + " |", "|---|" + "---|" * len(result["conditions"])]
    for row in result["rows"]:
        label = f"{row['name']}: {row['trained_env'].split('/')[-1].removesuffix('-v0')}"
        lines.append(f"| {label} | " + " | ".join(format(row["cells"][c][key], spec) for c in result["conditions"]) + " |")
    return "\n".join(lines)


@with_default_style
def plot_matrix(result: dict[str, Any], path: str | Path) -> Path:
    """Two heatmaps, the return with the supervisor and the collision rate alone, one row per trained
    agent and one column per evaluated condition; a box marks each agent's training condition."""
    rows, columns = result["rows"], result["conditions"]
    labels = [f"{r['name']}: {r['trained_env'].split('/')[-1].removesuffix('-v0')}" for r in rows]
    figure = Figure(figsize=(1.0 + 0.62 * len(columns), 1.6 + 0.9 * len(rows)), layout="constrained")
    axes = figure.subplots(2, 1)
    for ax, (key, title, cmap, spec) in zip(
        axes,
        (
            ("return_mean", "return with the supervisor (mean over seeds)", "viridis", ".0f"),
            ("collision_rate_alone", "collision rate alone (supervisor off)", "Reds", ".2f"),
        ),
        strict=True,
    ):
        values = np.array([[r["cells"][c][key] for c in columns] for r in rows])
        image = ax.imshow(values, cmap=cmap, aspect="auto")
        figure.colorbar(image, ax=ax, shrink=0.9)
        for i, j in np.ndindex(values.shape):
            ax.text(
                j,
                i,
                format(values[i, j], spec),
                ha="center",
                va="center",
                fontsize=7,
                color="white" if key == "return_mean" else "black",
            )
        for i, row in enumerate(rows):
            trained = Condition(row["trained_env"], 0.0).label
            if trained in columns:
                ax.add_patch(Rectangle((columns.index(trained) - 0.5, i - 0.5), 1, 1, fill=False, linewidth=2))
        ax.set_xticks(range(len(columns)), columns, rotation=60, ha="right", fontsize=7)
        ax.set_yticks(range(len(rows)), labels, fontsize=8)
        ax.set_title(
            f"{result['algo']}: {title}; {result['seeds']} seed(s) × {result['episodes_per_seed']} episodes", fontsize=9
        )
    return save_figure(figure, path)


__all__ = ["POLITENESS", "STYLES", "Condition", "conditions", "generalisation_matrix", "matrix_table", "plot_matrix"]
