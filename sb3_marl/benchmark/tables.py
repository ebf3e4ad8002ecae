"""The report's ``paper_table.md``: the final evaluations over seeds beside the paper's numbers and
claims, each claim checked per density, and the hand-written reference policies."""

from __future__ import annotations

from typing import Any

import numpy as np

from sb3_marl.benchmark.grid import EXPERIMENTS
from sb3_marl.benchmark.statistics import BOOTSTRAP_REPS, TrialLog, curve_summaries
from sb3_marl.envs import DENSITIES
from sb3_marl.evaluation import PROTOCOLS

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
    "merge": (
        "The merging paper's scenario (Chen et al. 2021): MADQN, MA2C, MAACKTR, MAPPO on the on-ramp merge",
        "its MA2C (with the supervisor and curriculum) 'consistently outperforms' the other learners",
    ),
    "curriculum": (
        "The merging paper's curriculum: MA2C at densities 2 and 3 from the easier density's model, on the merge",
        "how its MA2C is trained; the gain over training from scratch is not in the sources this project reads",
    ),
    "mobil-safety": (
        "Beyond the merging paper: MA2C on the merge trained and evaluated with the supervisor's MOBIL safety check",
        "not studied (the merging paper's supervisor checks the AVs' own headway only)",
    ),
    "cadence": (
        "Beyond the paper: MA2C's update cadence, one RMSprop step per AV slot against one per rollout",
        "not studied (the authors take one step per AV, on one road of 4-6 AVs)",
    ),
    "merge-cadence": (
        "Beyond the merging paper: MA2C's update cadence on the merge, one RMSprop step per AV slot against one per rollout",
        "not studied (the authors take one step per AV)",
    ),
    "copies": (
        "Beyond the paper: MA2C with 3, 9 and 18 scenario copies per VecEnv (the same budget in env steps)",
        "not studied (the authors' MA2C steps one env)",
    ),
    "rule-prior": (
        "Beyond the paper: MA2C and MAPPO started from the IDM/MOBIL rule driver and regularised toward it",
        "not studied (the authors' learners start from scratch); IDM/MOBIL's own row is in the reference section",
    ),
}

#: Experiment -> what a reader must know to compare its curves' returns.
EXPERIMENT_NOTES = {
    "comfort": "With the comfort term off, the reward (training and evaluation) has no comfort penalty, so the "
    "comfort-off returns are not comparable with the comfort-on ones; compare the acceleration std.",
    "politeness": "With p = 1 the HDVs themselves drive differently (MOBIL weighs their neighbours' gain), so the "
    "scenario, not only the learner, differs between the curves.",
}


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
        for density in DENSITIES:
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
        for (name, density), s in sorted(references.items(), key=lambda item: (item[0][0].endswith(", merge"), item[0][1]))
    ]
    lines = [
        "## Beyond the paper: hand-written reference policies",
        "",
        "Not learned (`sb3_marl/evaluation/baselines.py`): IDM/MOBIL picks the meta-action a human driver of the scenario "
        "would; cruise always IDLE; random uniform. The same 30 episodes as the final evaluations, in the "
        "default MA2C trial's scenario config (`, merge`: the merge MA2C trial's, on the merge), with the "
        "safety supervisor and without it. Return: mean ± std "
        "over the episodes; the IQM's CI resamples episodes (the learners' resample seeds).",
        "",
        "| policy | density | episodes | return: mean ± std over episodes | return: IQM [95 % CI] | collision rate "
        "| supervisor off: return | supervisor off: collision rate | lane changes / ep. | yields / ep. "
        "| mean speed [m/s] | accel. std [m/s²] | supervisor interventions |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
        *rows,
        "",
    ]
    for density in DENSITIES:
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
    for density in DENSITIES:
        finals: dict[str, dict[str, Any]] = {
            label: summary for label, (algo, variant) in curves.items() if (summary := summaries[algo, variant, density])
        }
        if len(finals) < len(curves):
            continue
        (first, a), (second, b) = list(finals.items())[:2]
        if experiment in ("reward", "sharing", "penalty", "safety", "ctde", "rule-prior"):
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


#: The headline table's learner rows: label -> (algorithm, variant); the paper's four learners first.
HEADLINE_ROWS: dict[str, tuple[str, str]] = {
    "MADQN": ("madqn", "default"),
    "MA2C (the paper's method)": ("ma2c", "default"),
    "MAACKTR": ("maacktr", "default"),
    "MAPPO": ("mappo", "default"),
    "MA2C, separate actor and critic": ("ma2c", "separate-networks"),
    "MA2C, safety training": ("ma2c", "safety-training"),
    "MA2C, rule prior": ("ma2c", "rule-prior"),
    "MA2C, rule prior as disagreement (floor 0.5)": ("ma2c", "rule-prior-agreement-0.5"),
}


def headline_table(
    summaries: dict[tuple[str, str, int], dict[str, Any] | None], references: dict[tuple[str, int], dict[str, Any]]
) -> str:
    """The markdown of ``headline.md``: the paper's Table 5 beside ours (with the supervisor) and the
    same episodes without it, for :data:`HEADLINE_ROWS` and IDM/MOBIL; "—" where a curve has no
    finished trial at a density."""

    def on(algo: str, variant: str, density: int) -> str:
        summary = summaries.get((algo, variant, density))
        if summary is None:
            return "—"
        paper = PAPER_RETURNS.get((algo, density)) if variant == "default" else None
        return f"{summary['return_mean']:.2f} ± {summary['return_std']:.2f}" + (f" ({paper[0]:.2f})" if paper else "")

    def alone(summary: dict[str, Any] | None, spread: bool = True) -> str:
        off = (summary or {}).get("supervisor_off")
        if not off:
            return "—"
        std = f" ± {off['return_std']:.2f}" if spread else ""
        return f"{off['return_mean']:.2f}{std} / {off['collision_rate']:.2f}"

    header = "| {} | density 1 | density 2 | density 3 |\n|---|---|---|---|"
    idm = {density: references.get(("idm-mobil", density)) for density in DENSITIES}
    supervised = [
        *(f"| {label} | " + " | ".join(on(*curve, d) for d in DENSITIES) + " |" for label, curve in HEADLINE_ROWS.items()),
        "| IDM/MOBIL (hand-written, same episodes) | "
        + " | ".join(f"{s['return_mean']:.2f} ± {s['return_std']:.2f}" if s else "—" for s in idm.values())
        + " |",
    ]
    unsupervised = [
        *(
            f"| {label} | " + " | ".join(alone(summaries.get((*curve, d))) for d in DENSITIES) + " |"
            for label, curve in HEADLINE_ROWS.items()
        ),
        "| IDM/MOBIL (not learned) | " + " | ".join(alone(s, spread=False) for s in idm.values()) + " |",
    ]
    return "\n".join(
        [
            "With the safety supervisor (the authors' protocol): final evaluation return, mean ± std over seeds of "
            "30 seeded episodes each, sampled actions; in parentheses the paper's Table 5 (mean, 2 seeds).",
            "",
            header.format("policy"),
            *supervised,
            "",
            "The same episodes without the supervisor (the policy alone): return mean ± std over seeds / collision rate.",
            "",
            header.format("policy alone (supervisor off)"),
            *unsupervised,
            "",
        ]
    )
