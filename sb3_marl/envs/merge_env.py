"""The multi-agent on-ramp merging scenario of Chen et al. (2021, arXiv 2105.05701; MARL_CAVs'
``merge_env_v1``) on the lane-change scenario's machinery: the same kernel, meta-actions, masks,
observation, supervisor and info, on the merging road (:mod:`sb3_marl.sim.merge_road`)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numba
import numpy as np
from highway_env.road.road import Road

from sb3_marl.envs import config as cfg
from sb3_marl.envs.lane_change_env import LaneChangeEnv
from sb3_marl.envs.reward import total_reward
from sb3_marl.safety.supervisor import Supervisor
from sb3_marl.sim import kernel
from sb3_marl.sim.drivers import nearer
from sb3_marl.sim.merge_road import (
    CONVERGING,
    ENDS,
    MAIN_AFTER,
    MAIN_BEFORE,
    MAIN_BESIDE,
    MERGE_END,
    MERGING_LANE,
    RAMP,
    ROAD_LENGTH,
    make_merge_road,
    merge_lanes,
    merge_spawn,
    obstacle_rows,
)
from sb3_marl.sim.traffic import TrafficSnapshot

#: The ramp's lanes: the straight section, the converging section, the merging lane.
RAMP_SIDE = (RAMP, CONVERGING, MERGING_LANE)
#: Lane number -> whether it is on the ramp's side (a lookup instead of np.isin on every step).
ON_RAMP_SIDE = np.isin(np.arange(max(RAMP_SIDE) + 1), RAMP_SIDE)
#: Lanes whose vehicles ``surrounding_vehicles`` searches on each lane (MARL_CAVs' road.py): the
#: lane and its neighbours along the route.
ROUTE = np.zeros((6, 6), dtype=np.bool_)
for _lane, _route in {
    MAIN_BEFORE: (MAIN_BEFORE, MAIN_BESIDE),
    MAIN_BESIDE: (MAIN_BEFORE, MAIN_BESIDE, MAIN_AFTER),
    MAIN_AFTER: (MAIN_BESIDE, MAIN_AFTER),
    RAMP: (RAMP, CONVERGING),
    CONVERGING: (RAMP, CONVERGING, MERGING_LANE),
    MERGING_LANE: (CONVERGING, MERGING_LANE),
}.items():
    ROUTE[_lane, list(_route)] = True
#: The other lane a vehicle's regional reward looks at (MARL_CAVs' ``_regional_reward``: the side
#: lane beside the merging lane, the ramp and main road seen across from each other; -1: none),
#: and the x [m] the vehicle must have passed for it.
ACROSS = np.array([CONVERGING, MERGING_LANE, MAIN_BESIDE, -1, -1, MAIN_BEFORE])
ACROSS_FROM = np.array([ENDS[0], -np.inf, -np.inf, np.inf, np.inf, -np.inf])
#: The lane after each lane that MARL_CAVs' supervisor headway also searches (-1: none; the merging
#: lane's is left out, as theirs).
NEXT_ON_ROUTE = np.array([MAIN_BESIDE, MAIN_AFTER, -1, -1, CONVERGING, MERGING_LANE])
HEADWAY_CAP = 60.0  # [m] MARL_CAVs' headway without a leader


class MergeEnv(LaneChangeEnv):
    """On-ramp merging: AVs on the main road and on the ramp, among IDM/MOBIL HDVs; the ramp's AVs
    and HDVs must change to the main road before the merging lane's obstacle.

    Everything of :class:`~sb3_marl.envs.lane_change_env.LaneChangeEnv` holds (actions, masks,
    observation, supervisor, info, ``place`` with the road's lane numbers), with the merging
    paper's differences: the spawn (:func:`~sb3_marl.sim.merge_road.merge_spawn`), its densities
    (:data:`~sb3_marl.envs.config.MERGE_DENSITIES`), no road end (vehicles drive on past the road,
    as in MARL_CAVs), the reward ``200·safety + 4·headway + 1·speed + 4·merging-lane cost`` (no
    comfort term by default) and the regional neighbour sets of MARL_CAVs' ``_regional_reward``.
    """

    scenario = cfg.MERGE

    @classmethod
    def default_config(cls) -> dict[str, Any]:
        return cfg.merge_default_config()

    def _priorities(self) -> Callable[[np.ndarray, int, Supervisor], np.ndarray] | None:
        return merge_priorities if self.config["supervisor_priority"] == "merging" else None

    def _road_data(self) -> tuple[np.ndarray, float]:
        return merge_lanes(float(self.config["speed_limit"])), np.inf

    def _make_road(self) -> Road:
        return make_merge_road(self.config, self.np_random)

    def _spawn(self) -> np.ndarray:
        return merge_spawn(self.config, self.n_avs, self.n_hdvs, self.np_random)

    def _obstacles(self) -> np.ndarray:
        return obstacle_rows()

    @property
    def road_length(self) -> float:
        return ROAD_LENGTH

    def _reward_terms(
        self, snapshot: TrafficSnapshot, crashed: np.ndarray, acceleration: np.ndarray, lane_change: np.ndarray
    ) -> dict[str, np.ndarray]:
        """The lane change's terms plus ``merging_lane``: -exp(-(x - merge end)² / (10 × merging
        lane length)) for an AV on the merging lane, else 0 (MARL_CAVs' ``Merging_lane_cost``)."""
        terms = super()._reward_terms(snapshot, crashed, acceleration, lane_change)
        n = snapshot.n_avs
        on_merging_lane = snapshot.lane[:n] == MERGING_LANE
        cost = -np.exp(-((snapshot.x[:n] - MERGE_END) ** 2) / (10 * ENDS[2]))
        terms["merging_lane"] = np.where(on_merging_lane, cost, 0.0)
        return terms

    def _total_reward(self, terms: dict[str, np.ndarray]) -> np.ndarray:
        return total_reward(terms, self.config) + self.config["merging_lane_weight"] * terms["merging_lane"]

    def _neighbour_sets(self, snapshot: TrafficSnapshot) -> np.ndarray:
        return regional_neighbours(self.state, self.n_avs)

    def _scenario_info(self, info: dict[str, Any]) -> None:
        """The merge's info: ``ramp_av`` (the AV started on the ramp), ``merge_time`` [s] (when a
        ramp AV reached the main road; NaN: not yet) and ``stranded`` (vehicles at a standstill,
        under 1 m/s, on the merging lane)."""
        state, n = self.state, self.n_avs
        on_ramp_side = ON_RAMP_SIDE[state[:n, kernel.LANE].astype(np.int64)]
        if self.steps == 0:  # a new situation (reset, place)
            self._ramp_avs = on_ramp_side
            self._merge_time = np.full(n, np.nan)
        merged = self._ramp_avs & np.isnan(self._merge_time) & ~on_ramp_side
        self._merge_time[merged] = self.steps_done / self.config["policy_frequency"]
        info["ramp_av"] = self._ramp_avs.copy()
        info["merge_time"] = self._merge_time.copy()
        stranded = (
            (state[:, kernel.LANE] == MERGING_LANE) & (state[:, kernel.SPEED] < 1.0) & (state[:, kernel.IS_OBSTACLE] == 0)
        )
        info["stranded"] = int(np.count_nonzero(stranded))


def merge_priorities(state: np.ndarray, n_avs: int, supervisor: Supervisor) -> np.ndarray:
    """(n_avs,) MARL_CAVs' order of service of the safety supervisor on the merging road, the smallest
    first: the AVs on the merging lane first, the nearer its end the earlier
    (-0.5 - (merging lane length - distance to its end) / merging lane length), then by headway
    (+ 0.5 log(headway / (headway_time × speed)) for a moving AV; headway: the nearest vehicle ahead
    on its lane or on the lane after it, capped at 60 m). MARL_CAVs breaks ties with unseeded noise;
    here the lower index goes first."""
    return _merge_priorities(state, n_avs, supervisor.headway_time, NEXT_ON_ROUTE)


@numba.njit(cache=True)
def _merge_priorities(state: np.ndarray, n_avs: int, headway_time: float, next_on_route: np.ndarray) -> np.ndarray:
    priority = np.zeros(n_avs)
    for i in range(n_avs):
        lane, x, speed = int(state[i, kernel.LANE]), state[i, kernel.X], state[i, kernel.SPEED]
        if lane == MERGING_LANE:
            priority[i] = -0.5 - (ENDS[2] - (MERGE_END - x)) / ENDS[2]
        headway = HEADWAY_CAP
        for j in range(state.shape[0]):
            if state[j, kernel.IS_OBSTACLE] or not state[j, kernel.X] > x:
                continue
            other = int(state[j, kernel.LANE])
            if other == lane or (next_on_route[lane] >= 0 and other == next_on_route[lane]):
                headway = min(headway, state[j, kernel.X] - x)
        if speed > 0:
            priority[i] += 0.5 * np.log(headway / (headway_time * speed))
    return priority


def regional_neighbours(state: np.ndarray, n_avs: int) -> np.ndarray:
    """(n_avs, n_avs) bool: MARL_CAVs' regional reward sets on the merging road: AV i, and the AVs
    among the vehicles just ahead of and behind it (``surrounding_vehicles``: by x, among the
    vehicles on its lane's route, :data:`ROUTE`) on its own lane and on the lane across
    (:data:`ACROSS`)."""
    return _regional_neighbours(state, n_avs, ROUTE, ACROSS, ACROSS_FROM)


@numba.njit(cache=True)
def _surrounding(state: np.ndarray, k: int, lane: int, route: np.ndarray) -> tuple[int, int]:
    """MARL_CAVs' ``Road.surrounding_vehicles``: (front, rear) of vehicle k among the vehicles on
    ``lane``'s route, by x (-1: none; obstacles left out)."""
    s = state[k, kernel.X]
    front = rear = -1
    s_front = s_rear = 0.0
    for j in range(state.shape[0]):
        if j == k or state[j, kernel.IS_OBSTACLE] or not route[lane, int(state[j, kernel.LANE])]:
            continue
        front, rear, s_front, s_rear = nearer(s, j, state[j, kernel.X], front, rear, s_front, s_rear)
    return front, rear


@numba.njit(cache=True)
def _regional_neighbours(
    state: np.ndarray, n_avs: int, route: np.ndarray, across: np.ndarray, across_from: np.ndarray
) -> np.ndarray:
    neighbours = np.eye(n_avs, dtype=np.bool_)
    for i in range(n_avs):
        lane = int(state[i, kernel.LANE])
        found = _surrounding(state, i, lane, route)
        for j in found:
            if 0 <= j < n_avs:
                neighbours[i, j] = True
        other = across[lane]
        if other >= 0 and state[i, kernel.X] > across_from[lane]:
            for j in _surrounding(state, i, other, route):
                if 0 <= j < n_avs:
                    neighbours[i, j] = True
    return neighbours
