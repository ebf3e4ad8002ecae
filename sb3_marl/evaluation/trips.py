"""The traffic view of evaluated episodes: one trip record per vehicle, AV and HDV (SUMO's
``tripinfo``, with its column names where it has them), and the traffic metrics derived from
those records and from the road's state at each policy step.

:class:`TripRecorder` is a step hook of :func:`~sb3_marl.evaluation.episodes.run_episodes`: it reads
the state array after the reset and after every policy step (5 Hz: times, decelerations, TTC
and headways are sampled at the policy step, 0.2 s), keeps one record per vehicle (its
``VEHICLE_ID``) and per-step sums; it adds nothing to an episode it is not given to (training
never records). The definitions, with their units, are in ``docs/traffic.md``.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sb3_marl.sim import kernel
from sb3_marl.sim.lanes import DIRECTION_X, LENGTH, ROAD, START_X

#: Trip-record columns (SUMO tripinfo's names) and units; one row per vehicle and episode.
TRIP_COLUMNS = {
    "seed": "",  # the episode's seed
    "id": "",  # the vehicle's number in the episode (AVs first)
    "vType": "",  # "AV" or "HDV"
    "depart": "s",  # time it entered the road (0: every vehicle starts on it)
    "arrival": "s",  # time it left the road's end (empty: still on the road at the episode's end)
    "departPos": "m",
    "arrivalPos": "m",  # x where it left the road, or where it was at the episode's end
    "routeLength": "m",  # distance driven along the road
    "duration": "s",  # time on the road
    "timeLoss": "s",  # time lost driving below its ideal speed
    "waitingTime": "s",  # time below 0.1 m/s
    "laneChanges": "",
    "maxDecel": "m/s²",  # the hardest braking, over a policy step
    "minTTC": "s",  # the shortest time-to-collision to its leader (empty: never closing in)
    "minTimeHeadway": "s",  # the shortest time gap to its leader (empty: never had one)
    "crashed": "",
}
#: Below this speed [m/s] a vehicle waits (SUMO's threshold).
WAITING_SPEED = 0.1
#: TTC thresholds [s] of the metrics' conflict shares.
TTC_THRESHOLDS = (1.5, 3.0)
#: A deceleration beyond this [m/s²] over a policy step is hard braking.
HARD_BRAKING = 3.0


@dataclass
class _Episode:
    """One episode's per-vehicle accumulators (indexed by vehicle id) and per-step sums."""

    seed: int | None
    n_avs: int
    ideal: np.ndarray  # [m/s] each vehicle's ideal speed
    depart_pos: np.ndarray
    last: np.ndarray  # the state's vehicle rows at the last step, by id (NaN rows: gone)
    arrival: np.ndarray
    time_loss: np.ndarray
    waiting: np.ndarray
    lane_changes: np.ndarray
    max_decel: np.ndarray
    min_ttc: np.ndarray
    min_headway: np.ndarray
    crashed: np.ndarray
    hard_braking: np.ndarray  # bool: braking hard at the last step
    headways: list[np.ndarray] = field(default_factory=list)  # [s] every vehicle-step's time gap to its leader
    time: float = 0.0
    sums: dict[str, float] = field(default_factory=dict)


class TripRecorder:
    """Trip records and traffic metrics of the episodes it is called on (a ``StepHook``), on the
    road of each episode's env: its trips end where the road does (the lane change's 520 m; on the
    merge, the main road's end past the merge, 520 m, where its lanes end); an AV's ideal speed is
    the top of its target-speed ladder, an HDV's its IDM target speed; a lane change is a new lane
    of the same road (:mod:`sb3_marl.sim.lanes`)."""

    def __init__(self) -> None:
        self.episodes: list[_Episode] = []
        self.road_end, self.dt, self.ideal_av_speed = 0.0, 0.0, 0.0
        self.lanes = np.zeros((0, 0))

    def __call__(self, env: Any, info: dict) -> None:
        if info["step"] == 0:
            self.start(env.state, env.n_avs, getattr(env.unwrapped, "np_random_seed", None), env.horizon, env.config)
        else:
            self.step(env.state)

    def start(self, state: np.ndarray, n_avs: int, seed: int | None, horizon: Any, config: dict[str, Any]) -> None:
        """A new episode from its first ``state`` (the first ``n_avs`` rows AVs), on the road of the
        supervisor's ``horizon`` (its lanes, its end) with the scenario ``config``'s rates."""
        self.road_end, self.lanes = section_end(horizon), horizon.lanes
        self.dt, self.ideal_av_speed = 1.0 / config["policy_frequency"], float(np.max(config["target_speeds"]))
        rows = _vehicles(state)
        n = int(rows[:, kernel.VEHICLE_ID].max()) + 1
        ideal = np.full(n, self.ideal_av_speed)
        hdv = rows[:, kernel.IS_HDV] > 0
        ideal[rows[hdv, kernel.VEHICLE_ID].astype(np.int64)] = rows[hdv, kernel.TARGET_SPEED]
        last = np.full((n, kernel.COLUMNS), np.nan)
        last[rows[:, kernel.VEHICLE_ID].astype(np.int64)] = rows
        self.episodes.append(
            _Episode(
                seed=seed,
                n_avs=n_avs,
                ideal=np.maximum(ideal, WAITING_SPEED),
                depart_pos=last[:, kernel.X].copy(),
                last=last,
                arrival=np.full(n, np.nan),
                time_loss=np.zeros(n),
                waiting=np.zeros(n),
                lane_changes=np.zeros(n, dtype=np.int64),
                max_decel=np.zeros(n),
                min_ttc=np.full(n, np.inf),
                min_headway=np.full(n, np.inf),
                crashed=np.zeros(n, dtype=bool),
                hard_braking=np.zeros(n, dtype=bool),
                sums=dict.fromkeys(
                    (
                        "vehicle_steps",
                        *(f"ttc_{t}" for t in TTC_THRESHOLDS),
                        "speed_std_sum",
                        "steps",
                        "hdv_km",
                        "hdv_hard_brakes",
                        "arrivals",
                    ),
                    0.0,
                ),
            )
        )
        self._sample(self.episodes[-1], state, first=True)

    def step(self, state: np.ndarray) -> None:
        """The state after the episode's next policy step."""
        episode = self.episodes[-1]
        episode.time += self.dt
        rows = _vehicles(state)
        on_road = np.zeros(len(episode.last), dtype=bool)
        on_road[rows[:, kernel.VEHICLE_ID].astype(np.int64)] = rows[:, kernel.X] <= self.road_end
        leaving = np.isnan(episode.arrival) & ~on_road  # every vehicle starts on the road
        episode.arrival[leaving] = episode.time
        episode.sums["arrivals"] += float(leaving.sum())
        self._sample(episode, state, first=False)

    def _sample(self, episode: _Episode, state: np.ndarray, first: bool) -> None:
        """Accumulate the vehicles on the road in ``state`` (after the reset: ``first``)."""
        rows = _vehicles(state)
        on_road = rows[rows[:, kernel.X] <= self.road_end]
        ids = on_road[:, kernel.VEHICLE_ID].astype(np.int64)
        speed = on_road[:, kernel.SPEED]
        if not first:
            previous = episode.last[ids]
            decel = (previous[:, kernel.SPEED] - speed) / self.dt
            episode.max_decel[ids] = np.maximum(episode.max_decel[ids], decel)
            lane, before = on_road[:, kernel.LANE].astype(np.int64), previous[:, kernel.LANE].astype(np.int64)
            episode.lane_changes[ids] += (lane != before) & (self.lanes[lane, ROAD] == self.lanes[before, ROAD])
            episode.time_loss[ids] += self.dt * np.clip(1 - speed / episode.ideal[ids], 0, None)
            episode.waiting[ids] += self.dt * (speed < WAITING_SPEED)
            hdv = on_road[:, kernel.IS_HDV] > 0
            hard = decel > HARD_BRAKING
            episode.sums["hdv_hard_brakes"] += float((hard & hdv & ~episode.hard_braking[ids]).sum())
            episode.hard_braking[ids] = hard
            episode.sums["hdv_km"] += float((on_road[hdv, kernel.X] - previous[hdv, kernel.X]).sum()) / 1000
        episode.crashed[ids] |= on_road[:, kernel.CRASHED] > 0
        gap, closing = leader_gaps(on_road, state[state[:, kernel.IS_OBSTACLE] > 0])
        ttc = np.where((closing > 0) & (gap > 0), gap / np.where(closing > 0, closing, 1), np.inf)
        headway = np.where(np.isfinite(gap) & (speed > 0), np.maximum(gap, 0) / np.where(speed > 0, speed, 1), np.inf)
        episode.min_ttc[ids] = np.minimum(episode.min_ttc[ids], ttc)
        episode.min_headway[ids] = np.minimum(episode.min_headway[ids], headway)
        sums = episode.sums
        sums["vehicle_steps"] += len(ids)
        for threshold in TTC_THRESHOLDS:
            sums[f"ttc_{threshold}"] += float((ttc < threshold).sum())
        episode.headways.append(headway[np.isfinite(headway)])
        if len(ids) > 1:
            sums["speed_std_sum"] += float(speed.std())
            sums["steps"] += 1
        episode.last[ids] = on_road

    def trips(self) -> list[dict[str, Any]]:
        """One record per vehicle and episode (:data:`TRIP_COLUMNS`; NaN where undefined)."""
        rows = []
        for episode in self.episodes:
            for vid in range(len(episode.last)):
                arrived = not np.isnan(episode.arrival[vid])
                end_x = self.road_end if arrived else episode.last[vid, kernel.X]
                duration = episode.arrival[vid] if arrived else episode.time
                rows.append(
                    {
                        "seed": episode.seed,
                        "id": vid,
                        "vType": "AV" if vid < episode.n_avs else "HDV",
                        "depart": 0.0,
                        "arrival": float(episode.arrival[vid]),
                        "departPos": float(episode.depart_pos[vid]),
                        "arrivalPos": float(end_x),
                        "routeLength": float(end_x - episode.depart_pos[vid]),
                        "duration": float(duration),
                        "timeLoss": float(episode.time_loss[vid]),
                        "waitingTime": float(episode.waiting[vid]),
                        "laneChanges": int(episode.lane_changes[vid]),
                        "maxDecel": float(episode.max_decel[vid]),
                        "minTTC": _finite(episode.min_ttc[vid]),
                        "minTimeHeadway": _finite(episode.min_headway[vid]),
                        "crashed": bool(episode.crashed[vid]),
                    }
                )
        return rows

    def metrics(self) -> dict[str, float]:
        """The traffic metrics over every recorded episode (``docs/traffic.md``)."""
        trips = self.trips()
        sums = {key: sum(e.sums[key] for e in self.episodes) for key in self.episodes[0].sums} if self.episodes else {}
        hours = sum(e.time for e in self.episodes) / 3600

        def per_km(column: str, v_type: str) -> float:
            chosen = [t for t in trips if t["vType"] == v_type]
            km = sum(t["routeLength"] for t in chosen) / 1000
            return sum(t[column] for t in chosen) / km if km > 0 else float("nan")

        vehicle_steps = max(sums.get("vehicle_steps", 0.0), 1.0)
        headways = np.concatenate([h for e in self.episodes for h in e.headways]) if self.episodes else np.zeros(0)
        area = self.road_end / 1000 * hours  # [km h] of the road over the episodes (Edie's region)
        return {
            "throughput_veh_h": sums.get("arrivals", 0.0) / hours if hours > 0 else float("nan"),
            "flow_veh_h": sum(t["routeLength"] for t in trips) / 1000 / area if area > 0 else float("nan"),
            "density_veh_km": sum(t["duration"] for t in trips) / 3600 / area if area > 0 else float("nan"),
            **{f"travel_time_s_per_km_{v.lower()}": per_km("duration", v) for v in ("AV", "HDV")},
            **{f"time_loss_s_per_km_{v.lower()}": per_km("timeLoss", v) for v in ("AV", "HDV")},
            "speed_std": sums["speed_std_sum"] / sums["steps"] if sums.get("steps") else float("nan"),
            **{f"ttc_below_{t}_share": sums.get(f"ttc_{t}", 0.0) / vehicle_steps for t in TTC_THRESHOLDS},
            "hdv_hard_brakes_per_km": sums["hdv_hard_brakes"] / sums["hdv_km"] if sums.get("hdv_km") else float("nan"),
            "time_headway_median": float(np.median(headways)) if headways.size else float("nan"),
        }


#: Columns of a traffic table: title and how to format it from :meth:`TripRecorder.metrics`.
TRAFFIC_COLUMNS: tuple[tuple[str, Callable[[dict[str, float]], str]], ...] = (
    ("flow [veh/h]", lambda m: _format(m["flow_veh_h"], ".0f")),
    ("density [veh/km]", lambda m: _format(m["density_veh_km"], ".1f")),
    ("throughput [veh/h]", lambda m: _format(m["throughput_veh_h"], ".0f")),
    ("AV time loss [s/km]", lambda m: _format(m["time_loss_s_per_km_av"], ".2f")),
    ("HDV time loss [s/km]", lambda m: _format(m["time_loss_s_per_km_hdv"], ".2f")),
    ("speed std [m/s]", lambda m: _format(m["speed_std"], ".2f")),
    ("TTC < 1.5 s", lambda m: _format(m["ttc_below_1.5_share"], ".4f")),
    ("TTC < 3 s", lambda m: _format(m["ttc_below_3.0_share"], ".4f")),
    ("HDV hard brakes/km", lambda m: _format(m["hdv_hard_brakes_per_km"], ".2f")),
    ("median time headway [s]", lambda m: _format(m["time_headway_median"], ".2f")),
)


def _format(value: float, spec: str) -> str:
    return "-" if np.isnan(value) else format(value, spec)


def traffic_table(rows: list[tuple[dict[str, Any], dict[str, float]]]) -> str:
    """A markdown table: per row, its label columns (e.g. ``{"policy": "ma2c", "supervisor": "on"}``)
    then :data:`TRAFFIC_COLUMNS` of its metrics."""
    labels = list(rows[0][0]) if rows else []
    lines = ["| " + " | ".join([*labels, *(title for title, _ in TRAFFIC_COLUMNS)]) + " |"]
    lines.append("|" + "---|" * (len(labels) + len(TRAFFIC_COLUMNS)))
    for label, metrics in rows:
        cells = [*(str(label[key]) for key in labels), *(cell(metrics) for _, cell in TRAFFIC_COLUMNS)]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def trips_csv(trips: list[dict[str, Any]]) -> str:
    """Trip records as CSV text (pandas-ready: ``pd.read_csv``), undefined values empty."""
    columns = list(trips[0]) if trips else list(TRIP_COLUMNS)
    out = io.StringIO()
    writer = csv.DictWriter(out, columns, lineterminator="\n")
    writer.writeheader()
    for trip in trips:
        writer.writerow({k: "" if isinstance(v, float) and np.isnan(v) else v for k, v in trip.items()})
    return out.getvalue()


def section_end(horizon: Any) -> float:
    """Where the road's trips end [m]: the supervisor ``horizon``'s road end, or where the road's
    lanes end if sooner (the merge's main road past the merge, 520 m)."""
    lanes = horizon.lanes
    return min(horizon.road_end, float(np.max(lanes[:, START_X] + lanes[:, LENGTH] * lanes[:, DIRECTION_X])))


def human_reference(
    env_id: str, n_episodes: int, seed: int = 0, config: dict[str, Any] | None = None, also: tuple[Any, ...] = ()
) -> TripRecorder:
    """The all-human reference: the episodes ``seed, seed + 1, ...`` (the AV counts cycling as in
    :func:`~sb3_marl.evaluation.episodes.evaluation_records`) with every AV replaced at the spawn by
    an HDV as the scenario spawns them (IDM + MOBIL, the config's HDV parameters, its speed its
    target), driven by the compiled road for the episode's duration (or until every vehicle left),
    recorded as the policies' episodes are (and by the recorders ``also``, fed ``start`` and ``step`` as it is)."""
    from sb3_marl.envs import av_counts, make_scenario
    from sb3_marl.sim import dynamics
    from sb3_marl.sim.road import vehicle_state

    recorder, counts = TripRecorder(), av_counts(env_id, config)
    envs = {n: make_scenario(env_id, {**(config or {}), "n_avs": n}) for n in counts}  # one per AV count, reset per episode
    for episode in range(n_episodes):
        env = envs[counts[episode % len(counts)]]
        env.reset(seed=seed + episode)
        rows, h = env.state, env.horizon
        vehicles = rows[:, kernel.IS_OBSTACLE] == 0
        x, y, lane, speed = (rows[vehicles, column] for column in (kernel.X, kernel.Y, kernel.LANE, kernel.SPEED))
        state = np.concatenate([vehicle_state(env.config, x, lane, speed, 0, y=y), rows[~vehicles]])
        recorders = (recorder, *also)
        for each in recorders:
            each.start(state, 0, seed + episode, h, env.config)
        frames = int(env.config["simulation_frequency"] // env.config["policy_frequency"])
        no_action, dt = np.zeros(0, dtype=np.int64), 1.0 / env.config["simulation_frequency"]
        for _ in range(env.max_steps):
            state = dynamics.policy_step(
                state, no_action, frames, dt, h.lanes, h.road_end, h.speed_limit, h.ladder, no_action > 0
            )
            for each in recorders:
                each.step(state)
            if not (_vehicles(state)[:, kernel.X] <= recorder.road_end).any():
                break
    for env in envs.values():
        env.close()
    return recorder


def _vehicles(state: np.ndarray) -> np.ndarray:
    return state[state[:, kernel.IS_OBSTACLE] == 0]


def _finite(value: float) -> float:
    return float(value) if np.isfinite(value) else float("nan")


def leader_gaps(vehicles: np.ndarray, obstacles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per vehicle row: the bumper-to-bumper gap [m] to its leader, the nearest vehicle or obstacle
    ahead (larger x) whose body overlaps it laterally (|Δy| below the mean of their widths; inf:
    none), and how fast it closes in on it [m/s] (its speed minus the leader's; an obstacle stands)."""
    ahead = np.concatenate([vehicles, obstacles])
    obstacle = ahead[:, kernel.IS_OBSTACLE] > 0
    lengths = np.where(obstacle, kernel.OBSTACLE_LENGTH, kernel.LENGTH)
    widths = np.where(obstacle, kernel.OBSTACLE_WIDTH, kernel.WIDTH)
    dx = ahead[None, :, kernel.X] - vehicles[:, None, kernel.X]  # (vehicles, candidates) [m]
    overlapping = np.abs(ahead[None, :, kernel.Y] - vehicles[:, None, kernel.Y]) < (kernel.WIDTH + widths[None, :]) / 2
    dx = np.where(overlapping & (dx > 0), dx, np.inf)
    leader = np.argmin(dx, axis=1) if ahead.size else np.zeros(len(vehicles), dtype=np.int64)
    found = np.isfinite(dx[np.arange(len(vehicles)), leader]) if ahead.size else np.zeros(len(vehicles), dtype=bool)
    gap = np.where(found, dx[np.arange(len(vehicles)), leader] - (kernel.LENGTH + lengths[leader]) / 2, np.inf)
    leader_speed = np.where(obstacle[leader], 0.0, ahead[leader, kernel.SPEED])
    closing = np.where(found, vehicles[:, kernel.SPEED] - leader_speed, 0.0)
    return gap, closing


__all__ = [
    "HARD_BRAKING",
    "TRAFFIC_COLUMNS",
    "TRIP_COLUMNS",
    "TTC_THRESHOLDS",
    "WAITING_SPEED",
    "TripRecorder",
    "human_reference",
    "leader_gaps",
    "section_end",
    "traffic_table",
    "trips_csv",
]
