"""Episode metrics of the paper, computed from the scenario env's info.

The episode return is the paper's metric: the sum over the episode's steps of the mean reward
of the AVs. Driving metrics are averaged over AV-steps of AVs still on the road. Cooperation is
counted as lane changes and *yields* per episode (:meth:`EpisodeTrace.yields`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sb3_marl.envs.lane_change_env import ACTION_INDEX, LaneChangeEnv
from sb3_marl.sim import kernel

#: Policy steps (5 Hz) before a lane change in which the follower must have executed SLOWER to yield.
YIELD_WINDOW_STEPS = 5
#: [m] the largest gap from the follower (behind, in the target lane) to the lane-changing AV.
YIELD_GAP_M = 40.0
#: Policy steps after the lane change starts at which the follower's speed drop is measured.
AFTER_STEPS = 5


@dataclass(frozen=True)
class CooperativeLaneChange:
    """AV ``changer`` starts a lane change at ``step`` of the episode with seed ``episode_seed``
    (``n_avs`` AVs); AV ``yielder``, behind it in the target lane, slowed by ``speed_drop`` m/s."""

    episode_seed: int
    n_avs: int
    step: int
    changer: int
    yielder: int
    speed_drop: float  # [m/s] yielder's speed before the window minus its speed after the change


@dataclass
class EpisodeTrace:
    """Per step of one episode, per AV: x [m], lane index, target lane index, speed [m/s],
    executed action, lane-change start; the input of the yield detector."""

    seed: int
    n_avs: int
    x: list[np.ndarray] = field(default_factory=list)
    lane: list[np.ndarray] = field(default_factory=list)
    target_lane: list[np.ndarray] = field(default_factory=list)
    speed: list[np.ndarray] = field(default_factory=list)
    executed: list[np.ndarray] = field(default_factory=list)
    lane_change: list[np.ndarray] = field(default_factory=list)

    def record(self, env: LaneChangeEnv, info: dict) -> None:
        avs = env.state[: env.n_avs]
        self.x.append(avs[:, kernel.X].copy())
        self.lane.append(avs[:, kernel.LANE].astype(np.int64))
        self.target_lane.append(avs[:, kernel.TARGET_LANE].astype(np.int64))
        self.speed.append(avs[:, kernel.SPEED].copy())
        self.executed.append(np.asarray(info.get("executed_action", np.full(env.n_avs, -1))))
        self.lane_change.append(np.asarray(info.get("lane_change", np.zeros(env.n_avs, dtype=bool))))

    def yields(self) -> list[CooperativeLaneChange]:
        """Every lane change of this episode that an AV behind in the target lane yielded to: in
        the :data:`YIELD_WINDOW_STEPS` steps up to the lane change's start, the follower (at most
        :data:`YIELD_GAP_M` m behind, in the target lane) executed SLOWER, and
        :data:`AFTER_STEPS` steps after the start it drives slower than before the window."""
        slower = ACTION_INDEX["SLOWER"]
        found = []
        for step in range(1, len(self.x) - AFTER_STEPS):
            for changer in np.flatnonzero(self.lane_change[step]):
                target = self.target_lane[step][changer]
                for follower in range(self.n_avs):
                    gap = self.x[step][changer] - self.x[step][follower]
                    if follower == changer or self.lane[step][follower] != target or not 0 < gap <= YIELD_GAP_M:
                        continue
                    first = max(1, step - YIELD_WINDOW_STEPS + 1)
                    if not any(self.executed[s][follower] == slower for s in range(first, step + 1)):
                        continue
                    drop = float(self.speed[first - 1][follower] - self.speed[step + AFTER_STEPS][follower])
                    if drop > 0:
                        found.append(CooperativeLaneChange(self.seed, self.n_avs, step, int(changer), follower, drop))
        return found


@dataclass
class EpisodeRecord:
    """One episode: return, length [steps], crash, and per-AV-step driving samples."""

    episode_return: float = 0.0
    length: int = 0
    crashed: bool = False
    speeds: list[float] = field(default_factory=list)  # [m/s]
    headways: list[float] = field(default_factory=list)  # [m]
    accelerations: list[float] = field(default_factory=list)  # [m/s²]
    lane_changes: int = 0
    yield_events: list[CooperativeLaneChange] = field(default_factory=list)  # :meth:`EpisodeTrace.yields`
    interventions: int = 0  # AV-steps whose action the safety supervisor replaced
    av_steps: int = 0  # AV-steps on the road
    rule_agreements: int = 0  # AV-steps on the road whose proposed action was the rule driver's
    rule_actions: np.ndarray | None = None  # the rule driver's actions in the current state
    merge_times: np.ndarray | None = None  # [s] on the merge: when each ramp AV merged (NaN: not)
    stranded: int = 0  # on the merge: vehicles at a standstill on the merging lane, at the end

    def add_step(self, reward: float, info: dict) -> None:
        """Accumulate one env step from the scalar (global) reward and the env's info."""
        on_road = ~info["exited"]
        self.episode_return += reward
        self.length += 1
        self.crashed = self.crashed or bool(info["crashed"].any())
        for samples, key in ((self.speeds, "speed"), (self.headways, "headway"), (self.accelerations, "acceleration")):
            samples.extend(np.asarray(info[key])[on_road].tolist())
        self.lane_changes += int(np.asarray(info["lane_change"]).sum())
        self.interventions += int(np.asarray(info.get("intervened", False))[on_road].sum())
        self.av_steps += int(on_road.sum())
        if self.rule_actions is not None:
            self.rule_agreements += int((np.asarray(info["proposed_action"]) == self.rule_actions)[on_road].sum())
        self.rule_actions = info.get("rule_action")
        if "merge_time" in info:
            self.merge_times = np.asarray(info["merge_time"])[np.asarray(info["ramp_av"])]
            self.stranded = int(info["stranded"])

    def add_slot_step(self, arrays: Any, slot: int) -> None:
        """Accumulate one AV's share of a parameter-sharing VecEnv step (row ``slot`` of its
        ``step_arrays``, :class:`~wrappers.step_arrays.StepArrays`): the copy's first AV adds the
        step and the global reward, every AV its crash flag, lane change and supervisor intervention."""
        if arrays.agent[slot] == 0:
            self.episode_return += float(arrays.global_reward[slot])
            self.length += 1
        self.crashed = self.crashed or bool(arrays.crashed[slot])
        self.lane_changes += int(arrays.lane_change[slot])
        if not arrays.exited[slot]:
            self.interventions += int(arrays.intervened[slot])
            self.av_steps += 1


def summarize(records: list[EpisodeRecord]) -> dict[str, float]:
    """Mean ± std return and the driving metrics over episodes."""
    returns = np.array([r.episode_return for r in records])

    def pooled(name: str) -> np.ndarray:
        return np.array([x for r in records for x in getattr(r, name)])

    return {
        "episodes": len(records),
        "return_mean": float(returns.mean()),
        "return_std": float(returns.std()),
        "length_mean": float(np.mean([r.length for r in records])),
        "collision_rate": float(np.mean([r.crashed for r in records])),
        "success_rate": float(np.mean([not r.crashed for r in records])),
        "speed_mean": float(pooled("speeds").mean()),
        "headway_mean": float(pooled("headways").mean()),
        "acceleration_std": float(pooled("accelerations").std()),
        "lane_changes_per_episode": float(np.mean([r.lane_changes for r in records])),
        "yields_per_episode": float(np.mean([len(r.yield_events) for r in records])),
        "intervention_rate": float(sum(r.interventions for r in records) / max(sum(r.av_steps for r in records), 1)),
        "rule_agreement": float(sum(r.rule_agreements for r in records) / max(sum(r.av_steps for r in records), 1)),
        **_merge_metrics(records),
    }


def _merge_metrics(records: list[EpisodeRecord]) -> dict[str, float]:
    """On the merge: the share of ramp AVs that merged, their mean time to merge [s] and the
    vehicles stranded on the merging lane per episode; nothing on the lane change."""
    if not records or records[0].merge_times is None:
        return {}
    times = np.concatenate([r.merge_times for r in records if r.merge_times is not None])
    merged = times[~np.isnan(times)]
    return {
        "merge_rate": float(merged.size / times.size) if times.size else float("nan"),
        "time_to_merge_mean": float(merged.mean()) if merged.size else float("nan"),
        "stranded_per_episode": float(np.mean([r.stranded for r in records])),
    }


#: Columns of a results table: title and how to format it from a :func:`summarize` summary.
TABLE_COLUMNS: tuple[tuple[str, Callable[[dict[str, float]], str]], ...] = (
    ("return", lambda s: f"{s['return_mean']:.2f} ± {s['return_std']:.2f}"),
    ("collision rate", lambda s: f"{s['collision_rate']:.2f}"),
    ("success rate", lambda s: f"{s['success_rate']:.2f}"),
    ("mean speed [m/s]", lambda s: f"{s['speed_mean']:.2f}"),
    ("mean headway [m]", lambda s: f"{s['headway_mean']:.1f}"),
    ("accel. std [m/s²]", lambda s: f"{s['acceleration_std']:.3f}"),
    ("lane changes/ep", lambda s: f"{s['lane_changes_per_episode']:.2f}"),
    ("yields/ep", lambda s: f"{s.get('yields_per_episode', float('nan')):.2f}"),
    ("supervisor interventions", lambda s: f"{s.get('intervention_rate', 0.0):.3f}"),
    ("steps/ep", lambda s: f"{s['length_mean']:.1f}"),
)
#: The merge's columns, where every row has them (:func:`_merge_metrics`).
MERGE_COLUMNS: tuple[tuple[str, Callable[[dict[str, float]], str]], ...] = (
    ("ramp AVs merged", lambda s: _defined(s["merge_rate"], ".3f")),
    ("time to merge [s]", lambda s: _defined(s["time_to_merge_mean"], ".2f")),
    ("stranded/ep", lambda s: f"{s['stranded_per_episode']:.2f}"),
)


def _defined(value: float, spec: str) -> str:
    """``value`` formatted, or ``-`` where it is undefined (NaN: no ramp AV, or none merged)."""
    return "-" if np.isnan(value) else format(value, spec)


def markdown_table(rows: list[tuple[dict[str, Any], dict[str, float]]]) -> str:
    """A markdown table: per row, its label columns (e.g. ``{"policy": "random"}``) then the metrics
    (the merge's too where every row has them)."""
    labels = list(rows[0][0]) if rows else []
    merge = bool(rows) and all("merge_rate" in summary for _, summary in rows)
    columns = TABLE_COLUMNS + (MERGE_COLUMNS if merge else ())
    titles = [*labels, *(title for title, _ in columns)]
    lines = ["| " + " | ".join(titles) + " |", "|" + "---|" * len(titles)]
    for label, summary in rows:
        cells = [str(label[key]) for key in labels] + [fmt(summary) for _, fmt in columns]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


__all__ = [
    "MERGE_COLUMNS",
    "TABLE_COLUMNS",
    "CooperativeLaneChange",
    "EpisodeRecord",
    "EpisodeTrace",
    "markdown_table",
    "summarize",
]
