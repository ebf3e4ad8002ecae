"""The merging road's rules as data and compiled functions (MARL_CAVs' ``merge_env_v1``): which
lanes a vehicle's neighbours are searched on, the supervisor's order of service and the regional
reward's neighbour sets. The merge env (:mod:`sb3_marl.envs.merge_env`) and the batched step
(:mod:`sb3_marl.envs.batch_kernel`) read them. Units: m, m/s, s."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from sb3_marl.sim import kernel
from sb3_marl.sim.drivers import nearer
from sb3_marl.sim.kernel import jit
from sb3_marl.sim.merge_road import (
    CONVERGING,
    ENDS,
    MAIN_AFTER,
    MAIN_BEFORE,
    MAIN_BESIDE,
    MERGE_END,
    MERGING_LANE,
    RAMP,
)

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


class MergeRules(NamedTuple):
    """The merging road's tables (above) and supervisor order, as compiled code takes them
    (:class:`~sb3_marl.envs.batch_kernel.StepParameters`' ``merge``; None there: the highway)."""

    route: np.ndarray
    across: np.ndarray
    across_from: np.ndarray
    next_on_route: np.ndarray
    merging_priority: bool  # the supervisor serves the AVs in the merge's order (supervisor_priority)


@jit
def _merge_priorities(state: np.ndarray, n_avs: int, headway_time: float, next_on_route: np.ndarray) -> np.ndarray:
    """(n_avs,) MARL_CAVs' order of service of the safety supervisor on the merging road, the smallest
    first: the AVs on the merging lane first, the nearer its end the earlier
    (-0.5 - (merging lane length - distance to its end) / merging lane length), then by headway
    (+ 0.5 log(headway / (headway_time [s] × speed)) for a moving AV; headway: the nearest vehicle
    ahead on its lane or on the lane after it (``next_on_route``), capped at 60 m). MARL_CAVs breaks
    ties with unseeded noise; here the lower index goes first."""
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


@jit
def _surrounding(state: np.ndarray, k: int, lane: int, route: np.ndarray) -> tuple[int, int]:
    """MARL_CAVs' ``Road.surrounding_vehicles``: (front, rear) of vehicle k among the vehicles on
    ``lane``'s route, by x (-1: none; obstacles left out)."""
    s = state[k, kernel.X]
    front = rear = kernel.NO_VEHICLE
    s_front = s_rear = 0.0
    for j in range(state.shape[0]):
        if j == k or state[j, kernel.IS_OBSTACLE] or not route[lane, int(state[j, kernel.LANE])]:
            continue
        front, rear, s_front, s_rear = nearer(s, j, state[j, kernel.X], front, rear, s_front, s_rear)
    return front, rear


@jit
def _regional_neighbours(
    state: np.ndarray, n_avs: int, route: np.ndarray, across: np.ndarray, across_from: np.ndarray
) -> np.ndarray:
    """(n_avs, n_avs) bool: MARL_CAVs' regional reward sets on the merging road: AV i, and the AVs
    among the vehicles just ahead of and behind it (``surrounding_vehicles``: by x, among the
    vehicles on its lane's route, ``route``: :data:`ROUTE`) on its own lane and on the lane across
    (``across``: :data:`ACROSS`, once past ``across_from`` [m])."""
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
