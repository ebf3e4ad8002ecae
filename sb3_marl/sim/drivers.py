"""How vehicles drive, compiled on the state array: neighbours in a lane, IDM car following,
steering towards a lane (highway-env's ``ControlledVehicle``), MOBIL lane changes with their timer
and abort rule (``IDMVehicle``), every vehicle's decision of a frame (:func:`act`), and the rule
driver's meta-action for each AV (:func:`rule_actions`), on the road's lane table ``lanes``
(:mod:`sb3_marl.sim.lanes`). Units: m, m/s, m/s², rad, s."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from sb3_marl.sim.kernel import (
    ACC_MAX,
    ACCELERATION,
    CRASHED,
    DELTA,
    HEADING,
    IDM_ACC,
    IDM_DECEL,
    IDM_DISTANCE,
    IDM_TIME,
    IS_HDV,
    IS_OBSTACLE,
    KP_A,
    KP_HEADING,
    KP_LATERAL,
    LANE,
    LANE_CHANGE_DELAY,
    LENGTH,
    MAX_BRAKING_IMPOSED,
    MAX_STEERING_ANGLE,
    MIN_ACC_GAIN,
    NO_VEHICLE,
    ON_LANE_MARGIN,
    POLITENESS,
    PRESENT,
    SPEED,
    STEERING,
    TARGET_LANE,
    TARGET_SPEED,
    TAU_PURSUIT,
    TIMER,
    X,
    Y,
    arcsin,
    arctan,
    argsort,
    clip,
    cos,
    jit,
    not_zero,
    sin,
    tan,
    wrap_to_pi,
)
from sb3_marl.sim.lanes import LEFT, RIGHT, ROAD, follow, heading_at, local_coordinates, on_lane_at, reachable_from
from sb3_marl.sim.meta_actions import available_actions

#: Lanes of at most this many vehicles are searched in one pass; longer ones by bisection.
SCANNED = 16


class LaneOrder(NamedTuple):
    """The vehicles on each lane in order along it, for ``Road.neighbour_vehicles``' search by
    bisection (:func:`lane_order`); positions must not change while it is in use."""

    s: np.ndarray  # (lanes, n) [m] every row's longitudinal coordinate on every lane
    # (lanes, n) int: each lane's first ``sizes`` entries are its rows: by s (ties: row order) on a
    # lane of more than SCANNED rows, else in row order
    members: np.ndarray
    sizes: np.ndarray  # (lanes,) int: vehicles on each lane


@jit
def lane_order(state: np.ndarray, lanes: np.ndarray) -> LaneOrder:
    """Which vehicles and obstacles are on each lane (highway-env's ``lane.on_lane`` with its 1 m
    margin: the membership ``Road.neighbour_vehicles`` searches), sorted along the lane."""
    n, n_lanes = state.shape[0], lanes.shape[0]
    s = np.empty((n_lanes, n))
    members = np.empty((n_lanes, n), dtype=np.int64)
    sizes = np.zeros(n_lanes, dtype=np.int64)
    for lane in range(n_lanes):
        for j in range(n):
            s[lane, j], lateral = local_coordinates(lanes, lane, state[j, X], state[j, Y])
            if state[j, PRESENT] and on_lane_at(lanes, lane, s[lane, j], lateral, ON_LANE_MARGIN):
                members[lane, sizes[lane]] = j
                sizes[lane] += 1
        if sizes[lane] > SCANNED:
            rows = members[lane, : sizes[lane]]
            rows[:] = rows[argsort(s[lane][rows])]
    return LaneOrder(s, members, sizes)


@jit
def _neighbours(state: np.ndarray, lanes: np.ndarray, order: LaneOrder, k: int, lane: int) -> tuple[int, int]:
    """``Road.neighbour_vehicles``: (front, rear) of vehicle k on ``lane`` (-1: none), vehicles
    and obstacles, by their longitudinal coordinate on ``lane``: the front is the nearest at or
    ahead of k's (the last of equals in row order), the rear the nearest behind (the first of
    equals), found by bisection in :class:`LaneOrder`."""
    s, rows, count = order.s, order.members, order.sizes[lane]
    s_k = s[lane, k]
    if count <= SCANNED:  # a few rows, in row order: one pass
        front = rear = NO_VEHICLE
        s_front = s_rear = 0.0
        for i in range(count):
            if rows[lane, i] != k:
                front, rear, s_front, s_rear = nearer(s_k, rows[lane, i], s[lane, rows[lane, i]], front, rear, s_front, s_rear)
        return front, rear
    low, high = 0, count  # bisection: rows[lane, low:count] are at or ahead of s_k
    while low < high:
        middle = (low + high) // 2
        if s[lane, rows[lane, middle]] < s_k:
            low = middle + 1
        else:
            high = middle
    rear = NO_VEHICLE
    if low > 0:
        first = low - 1
        while first > 0 and s[lane, rows[lane, first - 1]] == s[lane, rows[lane, first]]:
            first -= 1
        rear = rows[lane, first]
    front, i = NO_VEHICLE, low
    while i < count and rows[lane, i] == k:
        i += 1
    if i < count:
        nearest = s[lane, rows[lane, i]]
        while i < count and s[lane, rows[lane, i]] == nearest:
            if rows[lane, i] != k:
                front = rows[lane, i]
            i += 1
    return front, rear


@jit
def nearer(
    s: float, j: int, s_v: float, front: int, rear: int, s_front: float, s_rear: float
) -> tuple[int, int, float, float]:
    """One step of highway-env's front / rear search from the coordinate ``s`` [m]: vehicle j at
    ``s_v`` [m] replaces the front (the nearest at or ahead of ``s``, the last of equals) or the
    rear (the nearest behind, the first of equals) found so far (-1: none)."""
    if s <= s_v and (front < 0 or s_v <= s_front):
        front, s_front = j, s_v
    if s_v < s and (rear < 0 or s_v > s_rear):
        rear, s_rear = j, s_v
    return front, rear, s_front, s_rear


@jit
def _desired_gap(state: np.ndarray, ego: int, front: int) -> float:
    """``IDMVehicle.desired_gap`` [m], projected on the ego's direction."""
    cos_e, sin_e = cos(state[ego, HEADING]), sin(state[ego, HEADING])
    cos_f, sin_f = cos(state[front, HEADING]), sin(state[front, HEADING])
    v_e, v_f = state[ego, SPEED], state[front, SPEED]
    dv = (v_e * cos_e - v_f * cos_f) * cos_e + (v_e * sin_e - v_f * sin_f) * sin_e
    ab = state[ego, IDM_ACC] * state[ego, IDM_DECEL]
    return state[ego, IDM_DISTANCE] + v_e * state[ego, IDM_TIME] + v_e * dv / (2 * np.sqrt(ab))


@jit
def lane_distance(state: np.ndarray, lanes: np.ndarray, k: int, other: int) -> float:
    """``lane_distance_to``: how far ``other`` is ahead of vehicle k along k's lane [m]."""
    lane = int(state[k, LANE])
    return (
        local_coordinates(lanes, lane, state[other, X], state[other, Y])[0]
        - local_coordinates(lanes, lane, state[k, X], state[k, Y])[0]
    )


@jit
def idm(state: np.ndarray, lanes: np.ndarray, ego: int, front: int, speed_limit: float) -> float:
    """``IDMVehicle.acceleration`` [m/s²] of ``ego`` behind ``front`` (-1: free road; ego -1 or an
    obstacle: 0)."""
    # every path reads the arrays (a free road: the ego's gap to itself, unused), one exit: kernel.jit
    row = max(ego, 0)
    other = front if front >= 0 else row
    d, gap = lane_distance(state, lanes, row, other), _desired_gap(state, row, other)
    obstacle, a_max = state[row, IS_OBSTACLE], state[row, IDM_ACC]
    ratio = max(state[row, SPEED], 0.0) / abs(not_zero(clip(state[row, TARGET_SPEED], 0.0, speed_limit)))
    acceleration = a_max * (1 - ratio**DELTA)
    if front >= 0:
        acceleration -= a_max * (gap / not_zero(d)) ** 2.0
    return 0.0 if ego < 0 or obstacle else acceleration


@jit
def _steering(state: np.ndarray, lanes: np.ndarray, k: int, lane: int) -> float:
    """``ControlledVehicle.steering_control`` [rad] towards the centre of ``lane``."""
    longitudinal, lateral = local_coordinates(lanes, lane, state[k, X], state[k, Y])
    future_heading = heading_at(lanes, lane, longitudinal + state[k, SPEED] * TAU_PURSUIT)
    speed = not_zero(state[k, SPEED])
    lateral_speed_command = -KP_LATERAL * lateral
    heading_command = arcsin(clip(lateral_speed_command / speed, -1.0, 1.0))
    heading_ref = future_heading + clip(heading_command, -np.pi / 4, np.pi / 4)
    heading_rate_command = KP_HEADING * wrap_to_pi(heading_ref - state[k, HEADING])
    slip_angle = arcsin(clip(LENGTH / 2 / speed * heading_rate_command, -1.0, 1.0))
    steering_angle = arctan(2 * tan(slip_angle))
    return clip(steering_angle, -MAX_STEERING_ANGLE, MAX_STEERING_ANGLE)


@jit
def mobil(state: np.ndarray, lanes: np.ndarray, order: LaneOrder, k: int, lane: int, speed_limit: float) -> bool:
    """``IDMVehicle.mobil``: should HDV k move to ``lane``? (no planned route)."""
    new_preceding, new_following = _neighbours(state, lanes, order, k, lane)
    new_following_a = idm(state, lanes, new_following, new_preceding, speed_limit)
    new_following_pred_a = idm(state, lanes, new_following, k, speed_limit)
    if new_following_pred_a < -state[k, MAX_BRAKING_IMPOSED]:
        return False
    old_preceding, old_following = _neighbours(state, lanes, order, k, int(state[k, LANE]))
    self_pred_a = idm(state, lanes, k, new_preceding, speed_limit)
    self_a = idm(state, lanes, k, old_preceding, speed_limit)
    old_following_a = idm(state, lanes, old_following, k, speed_limit)
    old_following_pred_a = idm(state, lanes, old_following, old_preceding, speed_limit)
    jerk = (
        self_pred_a
        - self_a
        + state[k, POLITENESS] * (new_following_pred_a - new_following_a + old_following_pred_a - old_following_a)
    )
    return not jerk < state[k, MIN_ACC_GAIN]


@jit
def _change_lane_policy(state: np.ndarray, lanes: np.ndarray, order: LaneOrder, k: int, speed_limit: float) -> None:
    """``IDMVehicle.change_lane_policy`` of HDV k (sets its target lane and timer), for an HDV
    changing lanes or whose timer passed ``LANE_CHANGE_DELAY`` (``do_every``): :func:`act` tests
    that before the call, where the policy of any other HDV does nothing."""
    lane, target = int(state[k, LANE]), int(state[k, TARGET_LANE])
    if lane != target:  # a lane change is ongoing: abort it if another vehicle is moving into the lane
        if lanes[lane, ROAD] == lanes[target, ROAD]:
            for j in range(state.shape[0]):
                if j == k or not state[j, PRESENT] or state[j, IS_OBSTACLE]:
                    continue
                if int(state[j, LANE]) != target and int(state[j, TARGET_LANE]) == target:
                    d = lane_distance(state, lanes, k, j)
                    if 0 < d < _desired_gap(state, k, j):
                        state[k, TARGET_LANE] = lane
                        break
        return
    state[k, TIMER] = 0.0
    for side in (int(lanes[lane, LEFT]), int(lanes[lane, RIGHT])):
        if not reachable_from(lanes, side, state[k, X], state[k, Y]):
            continue
        if abs(state[k, SPEED]) < 1:
            continue
        if mobil(state, lanes, order, k, side, speed_limit):
            state[k, TARGET_LANE] = side


@jit
def leader(state: np.ndarray, lanes: np.ndarray, order: LaneOrder, k: int) -> int:
    """The vehicle (or obstacle) ahead of vehicle k on its own lane (``Road.neighbour_vehicles``'
    front; -1: none)."""
    return _neighbours(state, lanes, order, k, int(state[k, LANE]))[0]


@jit
def act(state: np.ndarray, lanes: np.ndarray, speed_limit: float) -> None:
    """``Road.act``: every vehicle, in road order, follows its road past a lane's end, then decides
    steering and acceleration (obstacles do nothing)."""
    n = state.shape[0]
    order = lane_order(state, lanes)  # positions are frozen during the act phase
    for k in range(n):
        if not state[k, PRESENT] or state[k, IS_OBSTACLE]:
            continue
        if not state[k, IS_HDV]:
            state[k, TARGET_LANE] = follow(lanes, int(state[k, TARGET_LANE]), state[k, X], state[k, Y])
            state[k, STEERING] = _steering(state, lanes, k, int(state[k, TARGET_LANE]))
            state[k, ACCELERATION] = KP_A * (state[k, TARGET_SPEED] - state[k, SPEED])
            continue
        if state[k, CRASHED]:
            continue
        state[k, TARGET_LANE] = follow(lanes, int(state[k, TARGET_LANE]), state[k, X], state[k, Y])
        # only an HDV changing lanes (the abort rule) or whose timer ran out has a decision to make
        # (highway-env's early returns, tested here: the call costs the reference counts of five arrays, kernel.jit)
        if state[k, LANE] != state[k, TARGET_LANE] or state[k, TIMER] > LANE_CHANGE_DELAY:
            _change_lane_policy(state, lanes, order, k, speed_limit)
        lane, target = int(state[k, LANE]), int(state[k, TARGET_LANE])
        steering = _steering(state, lanes, k, target)
        acceleration = idm(state, lanes, k, _neighbours(state, lanes, order, k, lane)[0], speed_limit)
        if lane != target:
            acceleration = min(acceleration, idm(state, lanes, k, _neighbours(state, lanes, order, k, target)[0], speed_limit))
        state[k, STEERING] = steering
        state[k, ACCELERATION] = clip(acceleration, -ACC_MAX, ACC_MAX)


@jit
def rule_actions(
    state: np.ndarray,
    n_avs: int,
    mask: np.ndarray | None,
    lanes: np.ndarray,
    ladder: np.ndarray,
    speed_limit: float,
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
    (left, then right) that is available (``mask``, (n_avs, 5) bool, the AVs' action masks;
    None: :func:`available_actions` on the ``ladder`` [m/s]) and that MOBIL accepts gives
    LANE_LEFT / LANE_RIGHT; otherwise its IDM acceleration behind its leader gives FASTER above
    ``acceleration_threshold`` [m/s²], SLOWER below its negative (each only where available),
    else IDLE. Meta-action indices as highway-env's (LANE_LEFT 0, IDLE 1, LANE_RIGHT 2, FASTER 3,
    SLOWER 4)."""
    if mask is None:
        available = available_actions(state, n_avs, lanes, ladder)
    else:
        available = mask
    order = lane_order(state, lanes)
    actions = np.ones(n_avs, dtype=np.int64)
    driver = state.copy()
    for i in range(n_avs):
        saved = driver[i, TARGET_SPEED], driver[i, POLITENESS], driver[i, MAX_BRAKING_IMPOSED], driver[i, MIN_ACC_GAIN]
        driver[i, TARGET_SPEED] = speed_limit
        driver[i, POLITENESS], driver[i, MAX_BRAKING_IMPOSED], driver[i, MIN_ACC_GAIN] = (
            politeness,
            max_braking_imposed,
            min_acc_gain,
        )
        lane = int(driver[i, LANE])
        changing = False
        if lane == int(driver[i, TARGET_LANE]) and abs(driver[i, SPEED]) >= 1:
            for action, side in ((0, int(lanes[lane, LEFT])), (2, int(lanes[lane, RIGHT]))):
                if side >= 0 and available[i, action] and mobil(driver, lanes, order, i, side, speed_limit):
                    actions[i], changing = action, True
                    break
        if not changing:
            acceleration = idm(driver, lanes, i, leader(driver, lanes, order, i), speed_limit)
            if acceleration > acceleration_threshold and available[i, 3]:
                actions[i] = 3
            elif acceleration < -acceleration_threshold and available[i, 4]:
                actions[i] = 4
        driver[i, TARGET_SPEED], driver[i, POLITENESS], driver[i, MAX_BRAKING_IMPOSED], driver[i, MIN_ACC_GAIN] = saved
    return actions
