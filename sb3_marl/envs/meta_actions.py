"""The AVs' meta-actions on the state array, compiled: which are available (highway-env's
``DiscreteMetaAction`` rules), the lane and target speed each sets (``MDPVehicle.act``), and the
speed ladder. Units: m, m/s."""

from __future__ import annotations

import numba
import numpy as np

from sb3_marl.envs.kernel import (
    LANE,
    LANE_VEHICLE_LENGTH,
    SPEED,
    TARGET_LANE,
    TARGET_SPEED,
    X,
    Y,
)


@numba.njit(cache=True)
def speed_index(speed: float, ladder: np.ndarray) -> int:
    """``MDPVehicle.speed_to_index``: the index of the target speed nearest ``speed`` [m/s] on the
    uniform ``ladder`` [m/s] (rounding half to even, as ``np.round``)."""
    top = ladder.size - 1
    return int(min(max(np.round((speed - ladder[0]) / (ladder[top] - ladder[0]) * top), 0), top))


@numba.njit(cache=True)
def reachable(state: np.ndarray, k: int, lane: int, n_lanes: int, lane_width: float, road_length: float) -> bool:
    """``StraightLane.is_reachable_from``: may vehicle k steer towards ``lane`` from where it is?"""
    lateral = state[k, Y] - lane * lane_width
    return 0 <= lane < n_lanes and abs(lateral) <= 2 * lane_width and 0 <= state[k, X] < road_length + LANE_VEHICLE_LENGTH


@numba.njit(cache=True)
def available_actions(
    state: np.ndarray, n_avs: int, n_lanes: int, lane_width: float, road_length: float, ladder: np.ndarray
) -> np.ndarray:
    """(n_avs, 5) bool: highway-env's ``DiscreteMetaAction.get_available_actions`` for each AV (the
    first ``n_avs`` rows): IDLE always, a lane change towards an existing lane reachable from the
    AV's position (sides of its current lane), FASTER / SLOWER unless its target speed is already
    the top / bottom of the ``ladder`` [m/s]."""
    mask = np.zeros((n_avs, 5), dtype=np.bool_)
    top = ladder.size - 1
    for i in range(n_avs):
        lane = int(state[i, LANE])
        mask[i, 0] = reachable(state, i, lane - 1, n_lanes, lane_width, road_length)
        mask[i, 1] = True
        mask[i, 2] = reachable(state, i, lane + 1, n_lanes, lane_width, road_length)
        index = speed_index(state[i, TARGET_SPEED], ladder)
        mask[i, 3], mask[i, 4] = index < top, index > 0
    return mask


@numba.njit(cache=True)
def meta_action_targets(
    state: np.ndarray, n_avs: int, n_lanes: int, lane_width: float, road_length: float, ladder: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(n_avs, 5) target lane and (n_avs, 5) target speed [m/s] of each AV (the first ``n_avs``
    rows) under each meta-action, as highway-env's ``MDPVehicle.act`` sets them (LANE_LEFT 0,
    IDLE 1, LANE_RIGHT 2, FASTER 3, SLOWER 4): a lane change moves the target lane by one if that
    lane is reachable, a speed change moves one step up or down the ``ladder`` [m/s] from the step
    nearest the AV's speed; past the ladder's or the road's edge nothing changes."""
    top = ladder.size - 1
    target_lane, target_speed = np.empty((n_avs, 5)), np.empty((n_avs, 5))
    for i in range(n_avs):
        lane = int(state[i, TARGET_LANE])
        target_lane[i, :] = lane
        for action, side in ((0, -1), (2, 1)):
            other = min(max(lane + side, 0), n_lanes - 1)
            if reachable(state, i, other, n_lanes, lane_width, road_length):
                target_lane[i, action] = other
        target_speed[i, :] = state[i, TARGET_SPEED]
        index = speed_index(state[i, SPEED], ladder)
        target_speed[i, 3] = ladder[min(index + 1, top)]
        target_speed[i, 4] = ladder[max(index - 1, 0)]
    return target_lane, target_speed
