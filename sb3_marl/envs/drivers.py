"""How vehicles drive, compiled on the state array: neighbours in a lane, IDM car following,
steering towards a lane (highway-env's ``ControlledVehicle``), MOBIL lane changes with their timer
and abort rule (``IDMVehicle``), every vehicle's decision of a frame (:func:`act`), and the rule
driver's meta-action for each AV (:func:`rule_actions`). Units: m, m/s, m/s², rad, s."""

from __future__ import annotations

import numba
import numpy as np

from sb3_marl.envs.kernel import (
    ACC_MAX,
    ACCELERATION,
    COMFORT_ACC_MAX,
    COMFORT_ACC_MIN,
    CRASHED,
    DELTA,
    DISTANCE_WANTED,
    HEADING,
    IS_HDV,
    KP_A,
    KP_HEADING,
    KP_LATERAL,
    LANE,
    LANE_CHANGE_DELAY,
    LANE_VEHICLE_LENGTH,
    LENGTH,
    MAX_BRAKING_IMPOSED,
    MAX_STEERING_ANGLE,
    MIN_ACC_GAIN,
    ON_LANE_MARGIN,
    POLITENESS,
    PRESENT,
    SPEED,
    STEERING,
    TARGET_LANE,
    TARGET_SPEED,
    TIME_WANTED,
    TIMER,
    X,
    Y,
    arcsin,
    arctan,
    clip,
    cos,
    not_zero,
    sin,
    tan,
    wrap_to_pi,
)
from sb3_marl.envs.meta_actions import available_actions, reachable


@numba.njit(cache=True)
def _neighbours(state: np.ndarray, on_lane: np.ndarray, k: int, lane: int) -> tuple[int, int]:
    """``Road.neighbour_vehicles``: (front, rear) of vehicle k on ``lane`` (-1: none)."""
    s = state[k, X]
    front = rear = -1
    s_front = s_rear = 0.0
    for j in range(state.shape[0]):
        if j == k or not on_lane[lane, j]:
            continue
        s_v = state[j, X]
        if s <= s_v and (front < 0 or s_v <= s_front):
            front, s_front = j, s_v
        if s_v < s and (rear < 0 or s_v > s_rear):
            rear, s_rear = j, s_v
    return front, rear


@numba.njit(cache=True)
def _desired_gap(state: np.ndarray, ego: int, front: int) -> float:
    """``IDMVehicle.desired_gap`` [m], projected on the ego's direction."""
    cos_e, sin_e = cos(state[ego, HEADING]), sin(state[ego, HEADING])
    cos_f, sin_f = cos(state[front, HEADING]), sin(state[front, HEADING])
    v_e, v_f = state[ego, SPEED], state[front, SPEED]
    dv = (v_e * cos_e - v_f * cos_f) * cos_e + (v_e * sin_e - v_f * sin_f) * sin_e
    ab = -COMFORT_ACC_MAX * COMFORT_ACC_MIN
    return DISTANCE_WANTED + v_e * TIME_WANTED + v_e * dv / (2 * np.sqrt(ab))


@numba.njit(cache=True)
def idm(state: np.ndarray, ego: int, front: int, speed_limit: float) -> float:
    """``IDMVehicle.acceleration`` [m/s²] of ``ego`` behind ``front`` (-1: free road; ego -1: 0)."""
    if ego < 0:
        return 0.0
    target = clip(state[ego, TARGET_SPEED], 0.0, speed_limit)
    ratio = max(state[ego, SPEED], 0.0) / abs(not_zero(target))
    acceleration = COMFORT_ACC_MAX * (1 - ratio**DELTA)
    if front >= 0:
        d = state[front, X] - state[ego, X]
        acceleration -= COMFORT_ACC_MAX * (_desired_gap(state, ego, front) / not_zero(d)) ** 2.0
    return acceleration


@numba.njit(cache=True)
def _steering(state: np.ndarray, k: int, lane: int, lane_width: float) -> float:
    """``ControlledVehicle.steering_control`` [rad] towards the centre of ``lane``."""
    lateral = state[k, Y] - lane * lane_width
    speed = not_zero(state[k, SPEED])
    lateral_speed_command = -KP_LATERAL * lateral
    heading_command = arcsin(clip(lateral_speed_command / speed, -1.0, 1.0))
    heading_ref = 0.0 + clip(heading_command, -np.pi / 4, np.pi / 4)
    heading_rate_command = KP_HEADING * wrap_to_pi(heading_ref - state[k, HEADING])
    slip_angle = arcsin(clip(LENGTH / 2 / speed * heading_rate_command, -1.0, 1.0))
    steering_angle = arctan(2 * tan(slip_angle))
    return clip(steering_angle, -MAX_STEERING_ANGLE, MAX_STEERING_ANGLE)


@numba.njit(cache=True)
def mobil(state: np.ndarray, on_lane: np.ndarray, k: int, lane: int, speed_limit: float) -> bool:
    """``IDMVehicle.mobil``: should HDV k move to ``lane``? (no planned route)."""
    new_preceding, new_following = _neighbours(state, on_lane, k, lane)
    new_following_a = idm(state, new_following, new_preceding, speed_limit)
    new_following_pred_a = idm(state, new_following, k, speed_limit)
    if new_following_pred_a < -state[k, MAX_BRAKING_IMPOSED]:
        return False
    old_preceding, old_following = _neighbours(state, on_lane, k, int(state[k, LANE]))
    self_pred_a = idm(state, k, new_preceding, speed_limit)
    self_a = idm(state, k, old_preceding, speed_limit)
    old_following_a = idm(state, old_following, k, speed_limit)
    old_following_pred_a = idm(state, old_following, old_preceding, speed_limit)
    jerk = (
        self_pred_a
        - self_a
        + state[k, POLITENESS] * (new_following_pred_a - new_following_a + old_following_pred_a - old_following_a)
    )
    return not jerk < state[k, MIN_ACC_GAIN]


@numba.njit(cache=True)
def _change_lane_policy(
    state: np.ndarray,
    on_lane: np.ndarray,
    k: int,
    n_lanes: int,
    lane_width: float,
    road_length: float,
    speed_limit: float,
) -> None:
    """``IDMVehicle.change_lane_policy`` of HDV k (sets its target lane and timer)."""
    lane, target = int(state[k, LANE]), int(state[k, TARGET_LANE])
    if lane != target:  # a lane change is ongoing: abort it if another vehicle is moving into the lane
        for j in range(state.shape[0]):
            if j != k and state[j, PRESENT] and int(state[j, LANE]) != target and int(state[j, TARGET_LANE]) == target:
                d = state[j, X] - state[k, X]
                if 0 < d < _desired_gap(state, k, j):
                    state[k, TARGET_LANE] = lane
                    break
        return
    if not state[k, TIMER] > LANE_CHANGE_DELAY:
        return
    state[k, TIMER] = 0.0
    for side in (lane - 1, lane + 1):
        if not reachable(state, k, side, n_lanes, lane_width, road_length):
            continue
        if abs(state[k, SPEED]) < 1:
            continue
        if mobil(state, on_lane, k, side, speed_limit):
            state[k, TARGET_LANE] = side


@numba.njit(cache=True)
def lane_occupancy(state: np.ndarray, n_lanes: int, lane_width: float, road_length: float) -> np.ndarray:
    """(n_lanes, n) bool: which vehicles are on each lane (highway-env's ``lane.on_lane`` with its
    1 m margin), the membership ``Road.neighbour_vehicles`` searches."""
    n = state.shape[0]
    on_lane = np.zeros((n_lanes, n), dtype=np.bool_)
    for j in range(n):
        if state[j, PRESENT]:
            for lane in range(n_lanes):
                lateral = state[j, Y] - lane * lane_width
                on_lane[lane, j] = abs(lateral) <= lane_width / 2 + ON_LANE_MARGIN and (
                    -LANE_VEHICLE_LENGTH <= state[j, X] < road_length + LANE_VEHICLE_LENGTH
                )
    return on_lane


@numba.njit(cache=True)
def leader(state: np.ndarray, on_lane: np.ndarray, k: int) -> int:
    """The vehicle ahead of vehicle k on its own lane (``Road.neighbour_vehicles``' front; -1: none)."""
    return _neighbours(state, on_lane, k, int(state[k, LANE]))[0]


@numba.njit(cache=True)
def act(state: np.ndarray, n_lanes: int, lane_width: float, road_length: float, speed_limit: float) -> None:
    """``Road.act``: every vehicle, in road order, decides steering and acceleration."""
    n = state.shape[0]
    on_lane = lane_occupancy(state, n_lanes, lane_width, road_length)  # positions are frozen during the act phase
    for k in range(n):
        if not state[k, PRESENT]:
            continue
        if not state[k, IS_HDV]:
            state[k, STEERING] = _steering(state, k, int(state[k, TARGET_LANE]), lane_width)
            state[k, ACCELERATION] = KP_A * (state[k, TARGET_SPEED] - state[k, SPEED])
            continue
        if state[k, CRASHED]:
            continue
        _change_lane_policy(state, on_lane, k, n_lanes, lane_width, road_length, speed_limit)
        lane, target = int(state[k, LANE]), int(state[k, TARGET_LANE])
        steering = _steering(state, k, target, lane_width)
        acceleration = idm(state, k, _neighbours(state, on_lane, k, lane)[0], speed_limit)
        if lane != target:
            acceleration = min(acceleration, idm(state, k, _neighbours(state, on_lane, k, target)[0], speed_limit))
        state[k, STEERING] = steering
        state[k, ACCELERATION] = clip(acceleration, -ACC_MAX, ACC_MAX)


@numba.njit(cache=True)
def rule_actions(
    state: np.ndarray,
    n_avs: int,
    n_lanes: int,
    lane_width: float,
    road_length: float,
    speed_limit: float,
    ladder: np.ndarray,
    politeness: float,
    max_braking_imposed: float,
    min_acc_gain: float,
    acceleration_threshold: float,
) -> np.ndarray:
    """(n_avs,) int: the meta-action a human driver (IDM + MOBIL, as the scenario's HDVs) would pick
    in each AV's place (the first ``n_avs`` rows), with the road's own :func:`idm` and :func:`mobil`.

    AV i is read as an HDV aiming at ``speed_limit`` [m/s] with the given MOBIL parameters
    (politeness, safe braking [m/s²], acceleration gain threshold [m/s²]); the other vehicles stay
    as they are. If it is not changing lanes and drives at 1 m/s or more, the first side lane
    (left, then right) that is available (:func:`available_actions`) and that MOBIL accepts gives
    LANE_LEFT / LANE_RIGHT; otherwise its IDM acceleration behind its leader gives FASTER above
    ``acceleration_threshold`` [m/s²], SLOWER below its negative (each only where available),
    else IDLE. Meta-action indices as highway-env's (LANE_LEFT 0, IDLE 1, LANE_RIGHT 2, FASTER 3,
    SLOWER 4)."""
    mask = available_actions(state, n_avs, n_lanes, lane_width, road_length, ladder)
    on_lane = lane_occupancy(state, n_lanes, lane_width, road_length)
    actions = np.ones(n_avs, dtype=np.int64)
    driver = state.copy()
    for i in range(n_avs):
        saved = driver[i].copy()
        driver[i, TARGET_SPEED] = speed_limit
        driver[i, POLITENESS], driver[i, MAX_BRAKING_IMPOSED], driver[i, MIN_ACC_GAIN] = (
            politeness,
            max_braking_imposed,
            min_acc_gain,
        )
        lane = int(driver[i, LANE])
        changing = False
        if lane == int(driver[i, TARGET_LANE]) and abs(driver[i, SPEED]) >= 1:
            for action, side in ((0, lane - 1), (2, lane + 1)):
                if 0 <= side < n_lanes and mask[i, action] and mobil(driver, on_lane, i, side, speed_limit):
                    actions[i], changing = action, True
                    break
        if not changing:
            acceleration = idm(driver, i, leader(driver, on_lane, i), speed_limit)
            if acceleration > acceleration_threshold and mask[i, 3]:
                actions[i] = 3
            elif acceleration < -acceleration_threshold and mask[i, 4]:
                actions[i] = 4
        driver[i] = saved
    return actions
