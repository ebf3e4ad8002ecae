"""The report's traffic view (``docs/traffic.md``) of the finished trials whose final evaluation
holds the traffic metrics (:func:`~sb3_marl.benchmark.trial.paper_evaluation`):

- ``traffic.md``: per road and density, the all-human reference, the hand-written policies and each
  learned curve (mean over seeds) on the final evaluation's episodes, under both supervisor
  protocols (:func:`~sb3_marl.evaluation.trips.traffic_table`'s columns);
- ``traffic.png``: flow, HDV time loss, the share of vehicle-time with TTC below 3 s and the hard
  braking imposed on HDVs against density, one row per road (supervisor on);
- ``time_space_<road>.png``: the first final-evaluation episode of the road's MA2C (the first
  seed, at the densest density with one) above the all-human reference of the same episode.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from sb3_marl.benchmark.statistics import REFERENCE_VARIANTS, TrialLog, reference_configs, select_trials
from sb3_marl.common.files import save_figure, write_text
from sb3_marl.envs import DENSITIES
from sb3_marl.evaluation.plotting import with_default_style
from sb3_marl.evaluation.trips import traffic_table

#: The figure's metrics and axis titles.
FIGURE_METRICS = {
    "flow_veh_h": "flow [veh/h]",
    "time_loss_s_per_km_hdv": "HDV time loss [s/km]",
    "ttc_below_3.0_share": "share of vehicle-time, TTC < 3 s",
    "hdv_hard_brakes_per_km": "hard brakes imposed on HDVs [/km]",
}
HUMAN = "all human (no AV)"
#: The learned curves the figure shows (the paper's variant of each road).
CURVES = ("(default)", "(merge)")


def curve_traffic(trials: list[TrialLog], algo: str, variant: str, density: int) -> dict[str, dict[str, float]] | None:
    """The traffic metrics of a curve's finished trials, mean over seeds, per protocol (``on`` /
    ``off``), and their number of seeds (``seeds``); None where no finished trial has them."""
    finals = [t.final() for t in select_trials(trials, algo, variant, density) if t.result is not None]
    finals = [f for f in finals if isinstance(f.get("traffic"), dict) and isinstance(f.get("supervisor_off"), dict)]
    if not finals:
        return None
    mean: dict[str, Any] = {"seeds": len(finals)}
    for protocol, pick in (("on", lambda f: f["traffic"]), ("off", lambda f: f["supervisor_off"]["traffic"])):
        metrics = [pick(f) for f in finals]
        mean[protocol] = {key: float(np.nanmean([float(m.get(key, np.nan)) for m in metrics])) for key in metrics[0]}
    return mean


def human_references(trials: list[TrialLog], log_folder: str | Path, seed: int) -> dict[tuple[str, int], dict[str, float]]:
    """The all-human reference's traffic metrics, keyed by (road, density), on the final evaluation's
    episodes (seeds ``seed ..``) where the road's MA2C has a finished trial, in its scenario config
    (:func:`~sb3_marl.benchmark.statistics.reference_configs`)."""
    from sb3_marl.benchmark.trial_files import FINAL_EVAL_EPISODES
    from sb3_marl.evaluation.trips import human_reference

    return {
        (road, density): human_reference(env_id, FINAL_EVAL_EPISODES, seed, config).metrics()
        for road, density, env_id, config in reference_configs(trials, log_folder)
    }


def traffic_rows(
    trials: list[TrialLog],
    references: dict[tuple[str, int], dict[str, Any]],
    humans: dict[tuple[str, int], dict[str, float]],
) -> list[tuple[dict[str, Any], dict[str, float]]]:
    """The rows of ``traffic.md``: per (road, density) of ``humans``, the all-human reference, the
    hand-written policies (``references``) and every learned curve with traffic metrics."""
    curves = sorted({(t.spec.algo, t.spec.variant) for t in trials})
    rows = []
    for (road, density), human in humans.items():
        place = {"road": road, "density": density}
        rows.append(({**place, "policy": HUMAN, "seeds": "-", "supervisor": "-"}, human))
        suffix = REFERENCE_VARIANTS[road][1]
        for (name, d), summary in references.items():
            if d == density and name.endswith(", merge") == (road == "merge") and "traffic" in summary:
                label = {**place, "policy": name.removesuffix(suffix), "seeds": "-"}
                rows += [({**label, "supervisor": "on"}, summary["traffic"])]
                rows += [({**label, "supervisor": "off"}, summary["supervisor_off"]["traffic"])]
        for algo, variant in curves:
            traffic = curve_traffic(trials, algo, variant, density)
            same_road = (variant == "merge") == (road == "merge")  # the merge's variants: the merge curve
            if traffic is not None and same_road:
                label = {**place, "policy": f"{algo} ({variant})", "seeds": traffic["seeds"]}
                rows += [({**label, "supervisor": protocol}, traffic[protocol]) for protocol in ("on", "off")]
    return rows


@with_default_style
def plot_traffic(rows: list[tuple[dict[str, Any], dict[str, float]]], path: Path) -> Path:
    """``traffic.png`` (see module doc) from :func:`traffic_rows`' supervisor-on rows and the
    all-human reference's; only the ``default`` / ``merge`` curves and IDM/MOBIL among the policies."""
    roads = list(dict.fromkeys(label["road"] for label, _ in rows))
    figure = Figure(figsize=(4.2 * len(FIGURE_METRICS), 3.4 * len(roads)), layout="constrained")
    axes = figure.subplots(len(roads), len(FIGURE_METRICS), squeeze=False)
    for row, road in enumerate(roads):
        mine = [(label, m) for label, m in rows if label["road"] == road and label["supervisor"] in ("on", "-")]
        shown = (HUMAN, "idm-mobil")
        policies = [p for p in dict.fromkeys(label["policy"] for label, _ in mine) if p in shown or p.endswith(CURVES)]
        for column, (key, title) in enumerate(FIGURE_METRICS.items()):
            ax = axes[row][column]
            for policy in policies:
                points = sorted((label["density"], m[key]) for label, m in mine if label["policy"] == policy)
                ax.plot(*zip(*points, strict=True), marker="o", label=policy, linestyle="--" if policy == HUMAN else "-")
            ax.set_xticks(sorted({label["density"] for label, _ in mine}))
            ax.set_xlabel("density")
            ax.set_title(f"{road}: {title}", fontsize=10)
        axes[row][0].legend(fontsize=8)
    return save_figure(figure, path)


def write_traffic(
    trials: list[TrialLog], log_folder: str | Path, out_dir: Path, seed: int, references: dict[tuple[str, int], dict[str, Any]]
) -> list[Path]:
    """``traffic.md``, ``traffic.png`` and the time–space diagrams (see module doc) into
    ``out_dir``; nothing where no finished trial has traffic metrics."""
    from sb3_marl.algos.common.policies import model_policy
    from sb3_marl.evaluation.traffic_plots import time_space_diagram
    from sb3_marl.runs.folders import find_run

    if not any(isinstance(t.final().get("traffic"), dict) for t in trials if t.result is not None):
        return []
    rows = traffic_rows(trials, references, human_references(trials, log_folder, seed))
    if not rows:
        return []
    header = (
        "# Traffic view of the final evaluations\n\n"
        f"Traffic metrics (docs/traffic.md) on the final evaluation's episodes (seeds {seed}..), learned "
        "curves averaged over their seeds, written by `sb3-marl benchmark report`.\n\n"
    )
    written = [
        write_text(out_dir / "traffic.md", header + traffic_table(rows) + "\n"),
        plot_traffic(rows, out_dir / "traffic.png"),
    ]
    for road, (variant, _) in REFERENCE_VARIANTS.items():
        finished = [t for d in reversed(DENSITIES) for t in select_trials(trials, "ma2c", variant, d) if t.result is not None]
        if finished:
            spec = finished[0].spec
            run = find_run(Path(log_folder) / "trials" / spec.trial_id, "ma2c", spec.env_id)
            policy = model_policy(run.load_model("cpu"))
            path = out_dir / f"time_space_{road}.png"
            written.append(time_space_diagram(policy, spec.env_id, seed, run.env_config, path, f"MA2C ({spec.trial_id})"))
    return written


__all__ = ["curve_traffic", "human_references", "plot_traffic", "traffic_rows", "write_traffic"]
