"""The penetration-rate sweep: a fixed number of vehicles on the road with a growing share of AVs
(0 % is the all-human reference), driven by a trained agent and by the rule driver (IDM/MOBIL
as meta-actions), each share on the same held-out episodes under both supervisor protocols; the
traffic metrics (:mod:`~sb3_marl.evaluation.trips`) and the collision rate against the share."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from tqdm import tqdm

from sb3_marl.common.files import save_figure
from sb3_marl.envs import scenario_of
from sb3_marl.envs.config import SCENARIO_DENSITIES
from sb3_marl.evaluation import evaluate_protocols
from sb3_marl.evaluation.episodes import Policy
from sb3_marl.evaluation.plotting import with_default_style
from sb3_marl.evaluation.trips import human_reference, traffic_table

#: AV shares [%] of the sweep.
SHARES = (0, 25, 50, 75, 100)
#: What the figure plots: metric key -> axis label.
PLOTTED = {
    "flow_veh_h": "flow [veh/h]",
    "time_loss_s_per_km_hdv": "HDV time loss [s/km]",
    "time_loss_s_per_km_av": "AV time loss [s/km]",
    "speed_std": "speed std [m/s]",
    "ttc_below_3.0_share": "share of vehicle-steps with TTC < 3 s",
    "hdv_hard_brakes_per_km": "HDV hard brakes per HDV-km",
    "time_headway_median": "median time headway [s]",
    "collision_rate": "collision rate (episodes)",
}


def densest_mix(env_id: str) -> int:
    """The vehicles of the scenario's densest mix: its density's most AVs plus most HDVs."""
    ranges = SCENARIO_DENSITIES[scenario_of(env_id)][int(env_id.split("density")[1].split("-")[0])]
    return ranges["avs"][1] + ranges["hdvs"][1]


def penetration_sweep(
    policies: dict[str, tuple[Policy | Any, dict[str, Any]]],
    env_id: str,
    vehicles: int,
    episodes: int,
    seed: int,
    shares: Iterable[int] = SHARES,
    progress: bool = True,
) -> dict[str, Any]:
    """Each share s of ``vehicles`` as AVs (round(s % × vehicles); 0: the all-human reference) on
    ``episodes`` episodes from ``seed``, for each of ``policies`` (label -> (policy, its env
    config)): one row per (share, policy, supervisor protocol) with the traffic metrics, the
    collision rate and the return."""
    shares = sorted(set(shares))
    rows: list[dict[str, Any]] = []
    jobs = tqdm(shares, desc="penetration", unit="share", disable=not progress)
    for share in jobs:
        n_avs = int(round(share / 100 * vehicles))
        if n_avs == 0:  # every vehicle an HDV: the all-human reference of the same episodes
            mix = {"n_avs": 1, "hdv_count_range": [vehicles - 1, vehicles - 1]}
            human = human_reference(env_id, episodes, seed, mix)
            crashed = {t["seed"]: False for t in human.trips()}
            for trip in human.trips():
                crashed[trip["seed"]] |= trip["crashed"]
            row = {"traffic": human.metrics(), "collision_rate": float(np.mean(list(crashed.values())))}
            rows.append({"share": share, "n_avs": 0, "policy": "all human (no AV)", "supervisor": "-", **row})
            continue
        mix = {"n_avs": n_avs, "hdv_count_range": [vehicles - n_avs, vehicles - n_avs]}
        for label, (policy, env_config) in policies.items():
            result = evaluate_protocols(policy, env_id, episodes, seed, {**env_config, **mix}, traffic=True)
            for supervisor, summary in (("on", result), ("off", result["supervisor_off"])):
                rl = {"collision_rate": summary["collision_rate"], "return_mean": summary["return_mean"]}
                rows.append(
                    {
                        "share": share,
                        "n_avs": n_avs,
                        "policy": label,
                        "supervisor": supervisor,
                        "traffic": summary["traffic"],
                        **rl,
                    }
                )
    return {
        "env_id": env_id,
        "vehicles": vehicles,
        "episodes": episodes,
        "episode_seeds": [seed, seed + episodes - 1],
        "rows": rows,
    }


def sweep_table(result: dict[str, Any]) -> str:
    """The sweep's rows as a markdown traffic table, with the AV count and the collision rate."""
    rows = [
        (
            {
                "AVs": f"{r['n_avs']} of {result['vehicles']}",
                "policy": r["policy"],
                "supervisor": r["supervisor"],
                "collision rate": f"{r['collision_rate']:.3f}" if "collision_rate" in r else "-",
            },
            r["traffic"],
        )
        for r in result["rows"]
    ]
    return traffic_table(rows)


@with_default_style
def plot_sweep(result: dict[str, Any], path: str | Path) -> Path:
    """One panel per metric of :data:`PLOTTED` against the AV share [%]: a line per (policy,
    supervisor protocol; dashed: alone), the all-human reference at 0 % as a black point."""
    figure = Figure(figsize=(13, 6.5), layout="constrained")
    axes = figure.subplots(2, 4).ravel()
    rows = result["rows"]
    lines = sorted({(r["policy"], r["supervisor"]) for r in rows if r["n_avs"] > 0})
    human = [r for r in rows if r["n_avs"] == 0]
    for ax, (key, label) in zip(axes, PLOTTED.items(), strict=True):
        for policy, supervisor in lines:
            mine = [r for r in rows if (r["policy"], r["supervisor"]) == (policy, supervisor)]
            x = [100 * r["n_avs"] / result["vehicles"] for r in mine]
            y = [r.get(key, r["traffic"].get(key, np.nan)) for r in mine]
            ax.plot(
                x, y, marker="o", linestyle="--" if supervisor == "off" else "-", label=f"{policy}, supervisor {supervisor}"
            )
        for r in human:
            value = r.get(key, r["traffic"].get(key, np.nan))
            ax.plot([0], [value], "ko", label="all human (no AV)")
        ax.set_xlabel("AV share [%]")
        ax.set_title(label, fontsize=9)
    handles, labels = axes[0].get_legend_handles_labels()
    figure.legend(handles, labels, loc="outside lower center", ncol=3, fontsize=8)
    figure.suptitle(
        f"{result['env_id']}: {result['vehicles']} vehicles, {result['episodes']} held-out episodes per point "
        f"(seeds {result['episode_seeds'][0]}..{result['episode_seeds'][1]})",
        fontsize=10,
    )
    return save_figure(figure, path)


__all__ = ["PLOTTED", "SHARES", "densest_mix", "penetration_sweep", "plot_sweep", "sweep_table"]
