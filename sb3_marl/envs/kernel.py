"""highway-env's road dynamics for the lane-change scenario, compiled (numba) on a state array.

One call of :func:`policy_step` runs the frames of a policy step for the whole road: every vehicle
acts (AVs: highway-env's ``ControlledVehicle`` steering and speed control towards the targets their
meta-actions set; HDVs: ``IDMVehicle``'s MOBIL lane-change policy, steering and IDM), every vehicle
moves (the kinematic bicycle model of ``Vehicle.step``, with the lane update of
``on_state_update``), then highway-env's pairwise collision test (spherical pre-check and
separating-axis test with the displacement of the next frame, ``impact`` and ``crashed`` as in
``RoadObject.handle_collisions``). Same operations in the same order as highway-env on the
scenario's road (straight lanes along +x from x = 0, lane k centred at y = k × lane width, one
road segment). The env keeps its road as this array (:func:`policy_step` steps it; the spawn is
:func:`sb3_marl.envs.road.spawn`), :mod:`sb3_marl.envs.simulator` builds highway-env objects from it
where they are needed, and the parity tests hold it to highway-env's own classes. Vehicle
dimensions, controller gains and IDM parameters are highway-env's class values (as the scenario
uses them); only MOBIL's politeness, safe braking and threshold are read per HDV (the scenario
config sets them, :func:`sb3_marl.envs.road.vehicle_state`).

Exactness: sin, cos and sqrt round as numpy's; numpy's float64 arcsin, arctan, tan and power use
SIMD routines on CPUs that have them (AVX-512 here), which differ from the C library's (used by
compiled code) in the last bit for a few % of inputs, and numpy's small dot products and 2 × 2
matrix products may fuse multiply-adds. Trajectories therefore agree with highway-env to about
1e-12 m per step rather than bit for bit; tests/envs/test_kernel.py checks the tolerance and that
episode outcomes (crashes, lane changes, lengths) are identical.

Units: positions and distances in m, speeds in m/s, accelerations in m/s², angles in rad, time in s.
"""

from __future__ import annotations

import numba
import numpy as np
from highway_env.road.lane import AbstractLane
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.controller import ControlledVehicle
from highway_env.vehicle.kinematics import Vehicle

# highway-env's parameters, read once (numba freezes module globals at compile time)
LENGTH = float(Vehicle.LENGTH)  # [m]
WIDTH = float(Vehicle.WIDTH)  # [m]
DIAGONAL = float(np.sqrt(LENGTH**2 + WIDTH**2))  # [m], as RoadObject.diagonal
MAX_SPEED = float(Vehicle.MAX_SPEED)  # [m/s]
MIN_SPEED = float(Vehicle.MIN_SPEED)  # [m/s]
KP_A = float(ControlledVehicle.KP_A)  # [1/s]
KP_HEADING = float(ControlledVehicle.KP_HEADING)  # [1/s]
KP_LATERAL = float(ControlledVehicle.KP_LATERAL)  # [1/s]
TAU_PURSUIT = float(ControlledVehicle.TAU_PURSUIT)  # [s]
MAX_STEERING_ANGLE = float(ControlledVehicle.MAX_STEERING_ANGLE)  # [rad]
ACC_MAX = float(IDMVehicle.ACC_MAX)  # [m/s²]
COMFORT_ACC_MAX = float(IDMVehicle.COMFORT_ACC_MAX)  # [m/s²]
COMFORT_ACC_MIN = float(IDMVehicle.COMFORT_ACC_MIN)  # [m/s²]
DISTANCE_WANTED = float(IDMVehicle.DISTANCE_WANTED)  # [m]
TIME_WANTED = float(IDMVehicle.TIME_WANTED)  # [s]
DELTA = float(IDMVehicle.DELTA)  # IDM exponent
LANE_CHANGE_DELAY = float(IDMVehicle.LANE_CHANGE_DELAY)  # [s]
LANE_VEHICLE_LENGTH = float(AbstractLane.VEHICLE_LENGTH)  # [m], lanes' end margin
ON_LANE_MARGIN = 1.0  # [m], highway-env's margin of "on the lane" in its neighbour search

#: Columns of the state array, one row per vehicle in ``road.vehicles`` order.
(
    X,
    Y,
    HEADING,
    SPEED,
    LANE,
    TARGET_LANE,
    TARGET_SPEED,
    IS_HDV,
    TIMER,
    CRASHED,
    COLLIDABLE,
    PRESENT,
    IMPACT_X,
    IMPACT_Y,
    HAS_IMPACT,
    STEERING,
    ACCELERATION,
    POLITENESS,
    MAX_BRAKING_IMPOSED,
    MIN_ACC_GAIN,
) = range(20)
COLUMNS = 20


@numba.njit(cache=True)
def sin(angle: float) -> float:
    """``np.sin``; sin(±0) = ±0 exactly without the call (most vehicles drive straight)."""
    return angle if angle == 0 else np.sin(angle)


@numba.njit(cache=True)
def cos(angle: float) -> float:
    """``np.cos``; cos(±0) = 1 exactly without the call."""
    return 1.0 if angle == 0 else np.cos(angle)


@numba.njit(cache=True)
def tan(angle: float) -> float:
    """``np.tan``; tan(±0) = ±0."""
    return angle if angle == 0 else np.tan(angle)


@numba.njit(cache=True)
def arcsin(value: float) -> float:
    """``np.arcsin``; arcsin(±0) = ±0."""
    return value if value == 0 else np.arcsin(value)


@numba.njit(cache=True)
def arctan(value: float) -> float:
    """``np.arctan``; arctan(±0) = ±0."""
    return value if value == 0 else np.arctan(value)


@numba.njit(cache=True)
def not_zero(value: float) -> float:
    """highway-env's ``utils.not_zero`` (eps 1e-2)."""
    if abs(value) > 1e-2:
        return value
    return 1e-2 if value >= 0 else -1e-2


@numba.njit(cache=True)
def wrap_to_pi(angle: float) -> float:
    """highway-env's ``utils.wrap_to_pi`` [rad] (Python's float modulo)."""
    return ((angle + np.pi) % (2 * np.pi)) - np.pi


@numba.njit(cache=True)
def clip(value: float, low: float = -1.0, high: float = 1.0) -> float:
    """``np.clip`` of one number: max with ``low``, then min with ``high``."""
    return min(max(value, low), high)


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
        if not _reachable(state, k, side, n_lanes, lane_width, road_length):
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
def _act(state: np.ndarray, n_lanes: int, lane_width: float, road_length: float, speed_limit: float) -> None:
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
def _closest_lane(x: float, y: float, heading: float, n_lanes: int, lane_width: float, road_length: float) -> int:
    """``RoadNetwork.get_closest_lane_index`` (first minimum of ``distance_with_heading``)."""
    best, best_distance = 0, np.inf
    angle = abs(wrap_to_pi(heading - 0.0))
    for lane in range(n_lanes):
        lateral = y - lane * lane_width
        distance = abs(lateral) + max(x - road_length, 0.0) + max(0 - x, 0.0) + 1.0 * angle
        if lane == 0 or distance < best_distance:
            best, best_distance = lane, distance
    return best


@numba.njit(cache=True)
def _move(state: np.ndarray, dt: float, n_lanes: int, lane_width: float, road_length: float) -> None:
    """``Vehicle.step`` of every vehicle (``IDMVehicle`` also advances its timer)."""
    for k in range(state.shape[0]):
        if not state[k, PRESENT]:
            continue
        if state[k, IS_HDV]:
            state[k, TIMER] += dt
        speed, heading = state[k, SPEED], state[k, HEADING]
        if state[k, CRASHED]:  # clip_actions
            state[k, STEERING] = 0.0
            state[k, ACCELERATION] = -1.0 * speed
        if speed > MAX_SPEED:
            state[k, ACCELERATION] = min(state[k, ACCELERATION], 1.0 * (MAX_SPEED - speed))
        elif speed < MIN_SPEED:
            state[k, ACCELERATION] = max(state[k, ACCELERATION], 1.0 * (MIN_SPEED - speed))
        beta = arctan(1 / 2 * tan(state[k, STEERING]))
        state[k, X] += speed * cos(heading + beta) * dt
        state[k, Y] += speed * sin(heading + beta) * dt
        if state[k, HAS_IMPACT]:
            state[k, X] += state[k, IMPACT_X]
            state[k, Y] += state[k, IMPACT_Y]
            state[k, CRASHED] = 1.0
            state[k, HAS_IMPACT] = 0.0
        state[k, HEADING] = heading + speed * sin(beta) / (LENGTH / 2) * dt
        state[k, SPEED] = speed + state[k, ACCELERATION] * dt
        state[k, LANE] = _closest_lane(state[k, X], state[k, Y], state[k, HEADING], n_lanes, lane_width, road_length)


@numba.njit(cache=True)
def _polygon(state: np.ndarray, k: int) -> np.ndarray:
    """``RoadObject.polygon``: (5, 2) corners [m], the first repeated."""
    c, s = cos(state[k, HEADING]), sin(state[k, HEADING])
    points = np.empty((5, 2))
    half_l, half_w = LENGTH / 2, WIDTH / 2
    for i, (px, py) in enumerate(((-half_l, -half_w), (-half_l, half_w), (half_l, half_w), (half_l, -half_w))):
        points[i, 0] = c * px + -s * py + state[k, X]
        points[i, 1] = s * px + c * py + state[k, Y]
    points[4] = points[0]
    return points


@numba.njit(cache=True)
def _project(polygon: np.ndarray, ax: float, ay: float) -> tuple[float, float]:
    low, high = np.inf, -np.inf
    for p in range(polygon.shape[0]):
        projected = polygon[p, 0] * ax + polygon[p, 1] * ay
        low, high = min(low, projected), max(high, projected)
    return low, high


@numba.njit(cache=True)
def _interval_distance(min_a: float, max_a: float, min_b: float, max_b: float) -> float:
    return min_b - max_a if min_a < min_b else min_a - max_b


@numba.njit(cache=True)
def _handle_collision(state: np.ndarray, i: int, j: int, dt: float) -> None:
    """``RoadObject.handle_collisions(i, j)``: crash flags and the impact of the next frame."""
    if not (state[i, COLLIDABLE] and state[j, COLLIDABLE]):
        return
    dx, dy = state[j, X] - state[i, X], state[j, Y] - state[i, Y]
    if np.sqrt(dx * dx + dy * dy) > (DIAGONAL + DIAGONAL) / 2 + state[i, SPEED] * dt:
        return
    a, b = _polygon(state, i), _polygon(state, j)
    # displacement_a - displacement_b, each velocity (speed × direction) × dt
    rel_x = state[i, SPEED] * cos(state[i, HEADING]) * dt - state[j, SPEED] * cos(state[j, HEADING]) * dt
    rel_y = state[i, SPEED] * sin(state[i, HEADING]) * dt - state[j, SPEED] * sin(state[j, HEADING]) * dt
    intersecting = will_intersect = True
    min_distance, axis_x, axis_y = np.inf, 0.0, 0.0
    done = False
    for polygon in (a, b):
        for p in range(4):
            nx, ny = -polygon[p + 1, 1] + polygon[p, 1], polygon[p + 1, 0] - polygon[p, 0]
            norm = np.sqrt(nx * nx + ny * ny)
            nx, ny = nx / norm, ny / norm
            min_a, max_a = _project(a, nx, ny)
            min_b, max_b = _project(b, nx, ny)
            if _interval_distance(min_a, max_a, min_b, max_b) > 0:
                intersecting = False
            velocity_projection = nx * rel_x + ny * rel_y
            if velocity_projection < 0:
                min_a += velocity_projection
            else:
                max_a += velocity_projection
            distance = _interval_distance(min_a, max_a, min_b, max_b)
            if distance > 0:
                will_intersect = False
            if not intersecting and not will_intersect:
                done = True
                break
            if abs(distance) < min_distance:
                min_distance = abs(distance)
                cx = (((a[0, 0] + a[1, 0]) + a[2, 0]) + a[3, 0]) / 4 - (((b[0, 0] + b[1, 0]) + b[2, 0]) + b[3, 0]) / 4
                cy = (((a[0, 1] + a[1, 1]) + a[2, 1]) + a[3, 1]) / 4 - (((b[0, 1] + b[1, 1]) + b[2, 1]) + b[3, 1]) / 4
                sign = 1.0 if cx * nx + cy * ny > 0 else -1.0
                axis_x, axis_y = sign * nx, sign * ny
        if done:
            break
    if will_intersect:
        tx, ty = min_distance * axis_x, min_distance * axis_y
        state[i, IMPACT_X], state[i, IMPACT_Y], state[i, HAS_IMPACT] = tx / 2, ty / 2, 1.0
        state[j, IMPACT_X], state[j, IMPACT_Y], state[j, HAS_IMPACT] = -tx / 2, -ty / 2, 1.0
    if intersecting:
        state[i, CRASHED] = state[j, CRASHED] = 1.0


@numba.njit(cache=True)
def speed_index(speed: float, ladder: np.ndarray) -> int:
    """``MDPVehicle.speed_to_index``: the index of the target speed nearest ``speed`` [m/s] on the
    uniform ``ladder`` [m/s] (rounding half to even, as ``np.round``)."""
    top = ladder.size - 1
    return int(min(max(np.round((speed - ladder[0]) / (ladder[top] - ladder[0]) * top), 0), top))


@numba.njit(cache=True)
def _reachable(state: np.ndarray, k: int, lane: int, n_lanes: int, lane_width: float, road_length: float) -> bool:
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
        mask[i, 0] = _reachable(state, i, lane - 1, n_lanes, lane_width, road_length)
        mask[i, 1] = True
        mask[i, 2] = _reachable(state, i, lane + 1, n_lanes, lane_width, road_length)
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
            if _reachable(state, i, other, n_lanes, lane_width, road_length):
                target_lane[i, action] = other
        target_speed[i, :] = state[i, TARGET_SPEED]
        index = speed_index(state[i, SPEED], ladder)
        target_speed[i, 3] = ladder[min(index + 1, top)]
        target_speed[i, 4] = ladder[max(index - 1, 0)]
    return target_lane, target_speed


@numba.njit(cache=True)
def drive(state: np.ndarray, dt: float, n_lanes: int, lane_width: float, road_length: float, speed_limit: float) -> None:
    """One frame of the road's driving (``Road.act``, then ``Vehicle.step`` of every vehicle) on
    ``state`` in place, without the collision test and the road end: the safety supervisor's
    prediction, with the same equations as :func:`policy_step`."""
    _act(state, n_lanes, lane_width, road_length, speed_limit)
    _move(state, dt, n_lanes, lane_width, road_length)


@numba.njit(cache=True)
def policy_step(
    state: np.ndarray,
    actions: np.ndarray,
    frames: int,
    dt: float,
    n_lanes: int,
    lane_width: float,
    road_length: float,
    speed_limit: float,
    ladder: np.ndarray,
) -> np.ndarray:
    """One policy step of the scenario on a copy of ``state``: the first ``actions.size`` rows (the
    AVs) take their meta-actions (:func:`meta_action_targets`), then ``frames`` frames of ``dt`` s
    run (``Road.act``, ``Road.step``); after each, vehicles past the road end leave: HDVs are
    removed, AVs stop colliding. Returns the new state without the removed vehicles.

    :param state: (n, :data:`COLUMNS`) one row per vehicle, the AVs first
    :param n_lanes: lanes along +x, lane k centred at y = k × ``lane_width`` [m]
    :param road_length: [m] length of the lanes
    :param speed_limit: [m/s] the lanes' speed limit (caps IDM's desired speed)
    :param ladder: [m/s] the AVs' target speeds
    """
    state = state.copy()
    n, n_avs = state.shape[0], actions.size
    target_lane, target_speed = meta_action_targets(state, n_avs, n_lanes, lane_width, road_length, ladder)
    for i in range(n_avs):
        state[i, TARGET_LANE], state[i, TARGET_SPEED] = target_lane[i, actions[i]], target_speed[i, actions[i]]
    for _ in range(frames):
        drive(state, dt, n_lanes, lane_width, road_length, speed_limit)
        for i in range(n):
            if state[i, PRESENT]:
                for j in range(i + 1, n):
                    if state[j, PRESENT]:
                        _handle_collision(state, i, j, dt)
        for k in range(n):
            if state[k, PRESENT] and state[k, X] > road_length:
                if state[k, IS_HDV]:
                    state[k, PRESENT] = 0.0
                else:
                    state[k, COLLIDABLE] = 0.0
    kept = np.flatnonzero(state[:, PRESENT])
    return state[kept] if kept.size < n else state


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
