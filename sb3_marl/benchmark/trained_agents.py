"""Trained agents by name, as rl-zoo's ``rl-trained-agents``: the finished trials of a benchmark
grid folder (the repository's ``results/paper-grid`` unless another grid folder is given), each
named by its grid variant (``zoo_configs/grids/variants.yml``), with two short names:

- ``paper``: the paper's recipe (variant ``default`` on the lane change, ``merge`` on the merge);
- ``safe``: the recipe that drives safely alone (``rule-prior-agreement-0.5``, the lane change's;
  ``zoo_configs/ma2c_safe.yml`` trains it).

A trial folder is an rl-zoo log folder, so a named agent is evaluated, filmed and uploaded as any run.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from sb3_marl.benchmark.grid import TrialSpec
from sb3_marl.benchmark.statistics import final_over_seeds, load_trials
from sb3_marl.benchmark.trial_files import RESULT, TRIAL
from sb3_marl.common.files import inside, read_json_object
from sb3_marl.envs import ENV_IDS, MERGE_ENV_IDS, scenario_of
from sb3_marl.envs.config import LANE_CHANGE, MERGE

#: The committed grid in a clone of the repository (absent from an installed wheel).
REPOSITORY_GRID = Path(__file__).resolve().parents[2] / "results" / "paper-grid"
#: Short names -> the variant they stand for, per scenario.
ALIASES = {"paper": {LANE_CHANGE: "default", MERGE: "merge"}, "safe": {LANE_CHANGE: "rule-prior-agreement-0.5"}}


def is_grid(folder: str | Path) -> bool:
    return (Path(folder) / "trials").is_dir()


def grid_of(folder: str | Path | None) -> Path:
    """``folder`` if it is a benchmark grid folder (it has ``trials/``), else the repository's grid.

    :raises FileNotFoundError: when neither is there (an installed package without the repository)
    """
    if folder is not None and is_grid(folder):
        return Path(folder)
    if is_grid(REPOSITORY_GRID):
        return REPOSITORY_GRID
    raise FileNotFoundError(
        f"no trained agents here: they ship in a clone of the repository ({REPOSITORY_GRID} is missing); "
        "give a benchmark grid folder with -f"
    )


def variant_of(name: str, env_id: str) -> str:
    """The grid variant ``name`` stands for on ``env_id``'s scenario (an alias or a variant's name)."""
    return ALIASES.get(name, {}).get(scenario_of(env_id), name)


def trained_agent(grid: str | Path, algo: str, env_id: str, name: str, seed: int = 0) -> Path:
    """The finished trial folder of the agent ``name`` (:data:`ALIASES` or a variant) of ``algo``
    on ``env_id``, trained with ``seed``.

    :raises FileNotFoundError: naming the agents that exist for ``algo`` on ``env_id``
    """
    grid = Path(grid)
    variant = variant_of(name, env_id)
    density = next(d for ids in (ENV_IDS, MERGE_ENV_IDS) for d, known in ids.items() if known == env_id)
    folder = grid / "trials" / f"{algo}_density{density}_{variant}_seed{seed}"
    if (folder / RESULT).is_file() and (folder / TRIAL).is_file():
        recorded = read_json_object(inside(folder / TRIAL, grid)).get("env_id")
        if recorded == env_id:
            return folder
    names = sorted({agent["name"] for agent in list_agents(grid, algo, env_id)})
    raise FileNotFoundError(
        f"no trained agent {name!r} (seed {seed}) of {algo} on {env_id} in {grid}: "
        f"trained agents there: {', '.join(names) or 'none'} (`sb3-marl trained-agents` lists them)"
    )


def list_agents(grid: str | Path, algo: str | None = None, env_id: str | None = None) -> list[dict[str, Any]]:
    """One row per (learner, scenario, name) with finished trials in ``grid``: its seeds, trial
    folder of the first seed and, over the seeds, the final evaluation (30 seeded episodes, the
    paper's protocol) with the safety supervisor and without it (:func:`final_over_seeds`)."""
    trials = [t for t in load_trials(grid, problems=[]) if t.result is not None]
    groups: dict[tuple[str, str, str], list[Any]] = {}
    for trial in trials:
        spec: TrialSpec = trial.spec
        if (algo is None or spec.algo == algo) and (env_id is None or spec.env_id == env_id):
            groups.setdefault((spec.algo, spec.env_id, spec.variant), []).append(trial)
    rows = []
    for (learner, scenario_id, variant), group in sorted(groups.items()):
        group.sort(key=lambda t: t.spec.seed)
        alias = [name for name, variants in ALIASES.items() if variants.get(scenario_of(scenario_id)) == variant]
        summary = final_over_seeds(group)
        assert summary is not None  # every trial of the group has finished
        rows.append(
            {
                **summary,
                "name": alias[0] if alias else variant,
                "variant": variant,
                "algo": learner,
                "env_id": scenario_id,
                "seeds": [t.spec.seed for t in group],
                "folder": str(Path(grid) / "trials" / group[0].spec.trial_id),
            }
        )
    return rows


def agents_table(rows: list[dict[str, Any]]) -> str:
    """:func:`list_agents`' rows as a markdown table."""
    lines = [
        "| name | algo | env | seeds | return, supervisor on | return alone | collision rate alone |",
        "|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        alone = row.get("supervisor_off")
        alone_cells = (
            f"{alone['return_mean']:.2f} ± {alone['return_std']:.2f} | {alone['collision_rate']:.3f}" if alone else "- | -"
        )
        name = row["name"] if row["name"] == row["variant"] else f"{row['name']} ({row['variant']})"
        lines.append(
            f"| {name} | {row['algo']} | {row['env_id']} | {len(row['seeds'])} | "
            f"{row['return_mean']:.2f} ± {row['return_std']:.2f} | {alone_cells} |"
        )
    return "\n".join(lines)


__all__ = ["ALIASES", "REPOSITORY_GRID", "agents_table", "grid_of", "is_grid", "list_agents", "trained_agent"]
