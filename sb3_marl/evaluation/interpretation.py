"""The paper's policy interpretation (its experiment 6): a cooperative lane change by trained AVs.

An AV *yields* when, in the second before another AV starts a lane change into its lane just
ahead of it, it executes SLOWER and then drives slower than before
(:meth:`~sb3_marl.evaluation.EpisodeTrace.yields`). :func:`find_cooperative_lane_change`
plays the evaluation episodes (the paper's protocol, :func:`~sb3_marl.evaluation.evaluation_records`)
and returns the yield with the largest speed drop; :func:`plot_cooperative_lane_change` replays
that episode with the scenario's renderer and draws road snapshots at three moments and the AVs'
speed traces.
"""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from sb3_marl.common.files import save_figure
from sb3_marl.envs import make_scenario
from sb3_marl.envs.lane_change_env import LaneChangeEnv
from sb3_marl.evaluation.episodes import Policy, evaluation_records, run_episodes
from sb3_marl.evaluation.metrics import AFTER_STEPS, YIELD_WINDOW_STEPS, CooperativeLaneChange, EpisodeTrace
from sb3_marl.evaluation.plotting import with_default_style

#: The three moments of the figure: before, at the start and after the lane change.
SNAPSHOT_OFFSETS = (-YIELD_WINDOW_STEPS, 0, 2 * AFTER_STEPS)
#: Renderer settings of the snapshots (drawing only): 7 px/m, a 171 m x 21 m view centred on the
#: lane-changing AV.
SNAPSHOT_VIEW = {"scaling": 7.0, "screen_width": 1200, "screen_height": 150, "centering_position": [0.5, 0.5]}


def find_cooperative_lane_change(
    policy: Policy, env_id: str, n_episodes: int, seed: int, config: dict | None = None
) -> tuple[CooperativeLaneChange | None, int]:
    """The yield with the largest speed drop in the evaluation episodes (seeds ``seed ..``), and
    how many yields there were; ``(None, 0)`` if no AV yielded to a lane change."""
    found = [event for record in evaluation_records(policy, env_id, n_episodes, seed, config) for event in record.yield_events]
    return (max(found, key=lambda event: event.speed_drop) if found else None), len(found)


@with_default_style
def plot_cooperative_lane_change(
    policy: Policy,
    env_id: str,
    event: CooperativeLaneChange,
    path: str | Path,
    config: dict | None = None,
    title: str = "",
) -> Path:
    """Replay ``event``'s episode with the scenario's renderer (the view follows the lane-changing
    AV, drawn orange; the yielding AV purple, other AVs green, HDVs blue) and write a figure of
    the road at :data:`SNAPSHOT_OFFSETS` steps from the lane change and the AVs' speed traces.

    :raises RuntimeError: if the replay does not reproduce the lane change (it should: episodes
        are seeded)
    """
    env = make_scenario(env_id, {**(config or {}), **SNAPSHOT_VIEW, "n_avs": event.n_avs}, render_mode="rgb_array")
    moments = [event.step + offset for offset in SNAPSHOT_OFFSETS]
    frames: dict[int, np.ndarray | None] = {}
    trace = EpisodeTrace(event.episode_seed, event.n_avs)

    def record(env: LaneChangeEnv, info: dict) -> None:
        trace.record(env, info)
        if info["step"] == 0:
            env.avs[event.changer].color = (255, 140, 0)
            env.avs[event.yielder].color = (150, 60, 200)
            env.render()  # creates the viewer, which then follows the lane-changing AV
            env.viewer.observer_vehicle = env.avs[event.changer]  # type: ignore[union-attr]
        if info["step"] in moments:
            frames[info["step"]] = env.render()

    run_episodes(env, policy, 1, event.episode_seed, on_step=record)
    env.close()
    if not (len(trace.lane_change) > event.step and trace.lane_change[event.step][event.changer]):
        raise RuntimeError(
            f"The replay of episode seed {event.episode_seed} did not reproduce the lane change of "
            f"AV {event.changer} at step {event.step}."
        )

    fig = Figure(figsize=(12, 8.5))
    axes = fig.subplots(len(moments) + 1, 1, gridspec_kw={"height_ratios": [1] * len(moments) + [2.5]})
    frequency = env.config["policy_frequency"]
    for ax, moment in zip(axes, moments):
        if moment in frames:
            ax.imshow(frames[moment])
        else:
            ax.text(0.5, 0.5, "episode over", ha="center")
        ax.set_axis_off()
        ax.set_title(
            f"t = {moment / frequency:.1f} s (step {moment}, {moment - event.step:+d} from the lane change)", fontsize=9
        )
    ax = axes[-1]
    time_s = np.arange(len(trace.speed)) / frequency
    speeds = np.array(trace.speed)
    for av in range(event.n_avs):
        if av == event.changer:
            ax.plot(time_s, speeds[:, av], color="darkorange", lw=2, label=f"AV {av + 1}: changes lane")
        elif av == event.yielder:
            ax.plot(time_s, speeds[:, av], color="purple", lw=2, label=f"AV {av + 1}: yields")
        else:
            ax.plot(time_s, speeds[:, av], color="gray", lw=0.8, alpha=0.7, label=f"AV {av + 1}")
    for moment in moments:
        ax.axvline(moment / frequency, color="black", ls=":", lw=0.8)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("speed [m/s]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, ncol=3)
    fig.suptitle(
        (title or f"Cooperative lane change: episode seed {event.episode_seed}, {event.n_avs} AVs")
        + "\norange: the AV changing lanes; purple: the AV yielding; green: other AVs; blue: HDVs",
        fontsize=10,
    )
    fig.tight_layout()
    path = Path(path)
    save_figure(fig, path)
    return path


def describe(event: CooperativeLaneChange | None, count: int) -> dict[str, Any]:
    """A JSON-able record of the search: the chosen event (or None) and the number of yields."""
    return {"yields_found": count, "chosen": asdict(event) if event else None}


__all__ = ["CooperativeLaneChange", "describe", "find_cooperative_lane_change", "plot_cooperative_lane_change"]
