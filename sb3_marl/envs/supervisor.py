"""The priority-based safety supervisor of the authors' MA2C (Chen et al. 2021, arXiv 2105.05701).

Every policy step, before the AVs act, the supervisor serves the AVs on the road one by one in
priority order: the smallest headway margin first (gap to the leader in the AV's lane [m] minus
speed [m/s] × ``headway_time`` [s]; equal margins: the lower AV index first, so runs stay
reproducible without drawing random numbers). For the AV being served it predicts the next
``supervisor_horizon`` s of the whole road, frame by frame at ``simulation_frequency`` Hz:

- every vehicle with highway-env's own controllers and kinematic bicycle model (the equations of
  :mod:`sb3_marl.envs.simulator`, on a light array copy of the vehicle states: no env copy);
- HDVs follow their leader by IDM (highway-env's ``IDMVehicle`` parameters, the leader in their
  lane and, while they change lanes, in the target lane); MOBIL decisions are not predicted;
- AVs already served keep their (possibly replaced) action, the others their proposed action;
  with ``supervisor_repeat_actions`` (default) every AV repeats its action at each policy step of
  the horizon, as it would if the policy (or the supervisor) chose it again: SLOWER keeps braking
  down the speed ladder, FASTER keeps speeding up. Held once, SLOWER only lowers the target speed
  by one step, which cannot stop an AV closing on a slow leader; repeated, it can, and the
  supervisor will keep choosing it while the danger lasts.

The *room* of the AV is the smallest bumper-to-bumper gap [m] over the horizon to any vehicle
whose body overlaps it laterally; bodies are the axis-aligned boxes around the (possibly tilted)
vehicle rectangles, and, as highway-env's own collision test, each gap is shortened by the
distance the two vehicles close within the next frame, so a negative room is a predicted
collision, with a little to spare. If the action's room is below ``supervisor_min_gap`` m
(default 2 m), it is replaced by the action available to the AV (the env's action mask) with the
largest room, ties in the order IDLE, SLOWER, FASTER, LANE_LEFT, LANE_RIGHT. The AVs are served
in two passes (:data:`PASSES`): the second re-checks each AV against the actions the others ended
with in the first (an AV served early was checked against proposals that may have been replaced
since). Served one at a time, two AVs whose lane changes conflict can still each find every option
unsafe and cross each other; a joint fallback then makes the AVs left short of room after a lane
change keep their lanes together (IDLE), when that leaves every AV more room. The prediction runs
as one compiled (numba) function per step; compiled code is cached on disk, so a fresh process
pays the compile time only once.
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.kinematics import Vehicle

from sb3_marl.envs.kernel import (
    ACC_MAX,
    COMFORT_ACC_MAX,
    COMFORT_ACC_MIN,
    DISTANCE_WANTED,
    KP_A,
    KP_HEADING,
    KP_LATERAL,
    LANE_VEHICLE_LENGTH,
    LENGTH,
    MAX_SPEED,
    MAX_STEERING_ANGLE,
    ON_LANE_MARGIN,
    TIME_WANTED,
    WIDTH,
    arcsin,
    arctan,
    cos,
    not_zero,
    sin,
    tan,
    wrap_to_pi,
)
from sb3_marl.envs.simulator import xy

NO_LEADER_GAP = 1e6  # [m], headway of an AV without leader (priority only)
#: Replacement candidates in tie order: IDLE, SLOWER, FASTER, LANE_LEFT, LANE_RIGHT
#: (highway-env's meta-action indices).
PREFERENCE = np.array([1, 4, 3, 0, 2], dtype=np.int64)
#: Speed-index change of each meta-action (FASTER +1, SLOWER -1) when actions repeat over the horizon.
SPEED_STEP = np.array([0, 0, 0, 1, -1], dtype=np.int64)
LANE_LEFT, IDLE, LANE_RIGHT = 0, 1, 2
#: Passes over the AVs in priority order (the second checks against the first pass's final actions).
PASSES = 2


@numba.njit(cache=True)
def _leader(k: int, lane_y: float, x: np.ndarray, y: np.ndarray, lane_width: float) -> int:
    """Index of the nearest vehicle at or ahead of vehicle k on the lane at ``lane_y`` m, or -1."""
    best, best_x = -1, 0.0
    for j in range(x.size):
        on_lane_ahead = j != k and abs(y[j] - lane_y) <= lane_width / 2 + ON_LANE_MARGIN and x[j] >= x[k]
        if on_lane_ahead and (best < 0 or x[j] < best_x):
            best, best_x = j, x[j]
    return best


@numba.njit(cache=True)
def _idm(k: int, front: int, x: np.ndarray, v: np.ndarray, desired_speed: float, delta: float) -> float:
    """highway-env's IDM acceleration [m/s²] of vehicle k behind ``front`` (-1: free road)."""
    ratio = max(v[k], 0.0) / abs(not_zero(desired_speed))
    acceleration = COMFORT_ACC_MAX * (1.0 - ratio**delta)
    if front >= 0:
        gap = (
            DISTANCE_WANTED
            + v[k] * TIME_WANTED
            + v[k] * (v[k] - v[front]) / (2.0 * np.sqrt(-COMFORT_ACC_MAX * COMFORT_ACC_MIN))
        )
        acceleration -= COMFORT_ACC_MAX * (gap / not_zero(x[front] - x[k])) ** 2
    return acceleration


@numba.njit(cache=True)
def _predict(
    x0: np.ndarray,
    y0: np.ndarray,
    h0: np.ndarray,
    v0: np.ndarray,
    target_y: np.ndarray,
    target_speed: np.ndarray,
    is_hdv: np.ndarray,
    delta: np.ndarray,
    crashed: np.ndarray,
    frames: int,
    dt: float,
    lane_width: float,
    n_lanes: int,
    speed_step: np.ndarray,
    ladder: np.ndarray,
    frames_per_step: int,
    ego: int,
    collidable: np.ndarray,
    floor: float,
) -> tuple[np.ndarray, float]:
    """(frames, 4, n) x, y [m], heading [rad] and speed [m/s] of every vehicle after each of
    ``frames`` frames of ``dt`` s, every vehicle driving towards its targets, and the room [m] of
    vehicle ``ego`` along it (see :func:`_room`; inf for ``ego`` -1). The prediction stops as soon
    as that room is at most ``floor`` m (it can only shrink): the rest of the path is then unset.

    ``speed_step`` (+1 FASTER, -1 SLOWER, 0 otherwise, per vehicle) repeats a speed change at every
    policy step (``frames_per_step`` frames) of the horizon, as ``MDPVehicle.act`` would on the
    speed ``ladder`` [m/s]: the AV keeps its action over the horizon."""
    n = x0.size
    x, y, h, v = x0.copy(), y0.copy(), h0.copy(), v0.copy()
    target_speed = target_speed.copy()
    acceleration, steering = np.zeros(n), np.zeros(n)
    path = np.empty((frames, 4, n))
    room = np.inf
    top = ladder.size - 1
    for frame in range(frames):
        if frame > 0 and frame % frames_per_step == 0:
            for k in range(n):
                if speed_step[k] != 0:
                    target_speed[k] = ladder[min(max(_speed_index(v[k], ladder) + speed_step[k], 0), top)]
        for k in range(n):  # act: every vehicle decides on the same frozen positions
            if crashed[k]:
                acceleration[k], steering[k] = -v[k], 0.0
                continue
            lateral_speed = -KP_LATERAL * (y[k] - target_y[k])
            heading_ref = min(max(arcsin(min(max(lateral_speed / not_zero(v[k]), -1.0), 1.0)), -np.pi / 4), np.pi / 4)
            heading_rate = KP_HEADING * wrap_to_pi(heading_ref - h[k])
            slip = arcsin(min(max(LENGTH / 2 / not_zero(v[k]) * heading_rate, -1.0), 1.0))
            steering[k] = min(max(arctan(2 * tan(slip)), -MAX_STEERING_ANGLE), MAX_STEERING_ANGLE)
            if is_hdv[k]:
                lane = min(max(int(np.floor(y[k] / lane_width + 0.5)), 0), n_lanes - 1)
                a = _idm(k, _leader(k, lane * lane_width, x, y, lane_width), x, v, target_speed[k], delta[k])
                if abs(target_y[k] - lane * lane_width) > 1e-9:
                    a = min(a, _idm(k, _leader(k, target_y[k], x, y, lane_width), x, v, target_speed[k], delta[k]))
                acceleration[k] = min(max(a, -ACC_MAX), ACC_MAX)
            else:
                acceleration[k] = KP_A * (target_speed[k] - v[k])
            if v[k] > MAX_SPEED:
                acceleration[k] = min(acceleration[k], MAX_SPEED - v[k])
        for k in range(n):  # step: kinematic bicycle model
            beta = arctan(0.5 * tan(steering[k]))
            x[k] += v[k] * cos(h[k] + beta) * dt
            y[k] += v[k] * sin(h[k] + beta) * dt
            h[k] += v[k] * sin(beta) / (LENGTH / 2) * dt
            v[k] += acceleration[k] * dt
        path[frame, 0], path[frame, 1], path[frame, 2], path[frame, 3] = x, y, h, v
        if ego >= 0:
            room = min(room, _frame_room(ego, x, y, h, v, collidable, dt))
            if room <= floor:
                break
    return path, room


@numba.njit(cache=True)
def _room(ego: int, path: np.ndarray, collidable: np.ndarray, dt: float) -> float:
    """Smallest bumper-to-bumper gap [m] along a predicted ``path`` (see :func:`_predict`) between
    vehicle ``ego`` and any collidable vehicle overlapping it laterally (negative: a collision)."""
    room = np.inf
    for frame in range(path.shape[0]):
        room = min(room, _frame_room(ego, path[frame, 0], path[frame, 1], path[frame, 2], path[frame, 3], collidable, dt))
    return room


@numba.njit(cache=True)
def _frame_room(
    ego: int, x: np.ndarray, y: np.ndarray, h: np.ndarray, v: np.ndarray, collidable: np.ndarray, dt: float
) -> float:
    """:func:`_room` of one frame's positions [m], headings [rad] and speeds [m/s]."""
    room = np.inf
    ego_x, ego_y = _half_extents(h[ego])
    for j in range(x.size):
        if j != ego and collidable[j]:
            other_x, other_y = _half_extents(h[j])
            # highway-env flags a collision when the bodies would meet within the next frame
            # (each moved by its velocity × dt): the gaps shrink by the closing speed × dt
            dx, dy = x[j] - x[ego], y[j] - y[ego]
            closing_x = (v[ego] * cos(h[ego]) - v[j] * cos(h[j])) * np.sign(dx)
            closing_y = (v[ego] * sin(h[ego]) - v[j] * sin(h[j])) * np.sign(dy)
            if abs(dy) - max(closing_y, 0.0) * dt < ego_y + other_y:
                room = min(room, abs(dx) - ego_x - other_x - max(closing_x, 0.0) * dt)
    return room


@numba.njit(cache=True)
def _speed_index(speed: float, ladder: np.ndarray) -> int:
    """``MDPVehicle.speed_to_index``: the index of the target speed nearest ``speed`` [m/s] on the
    uniform ``ladder`` [m/s] (rounding half to even, as ``np.round``)."""
    top = ladder.size - 1
    return int(min(max(np.round((speed - ladder[0]) / (ladder[top] - ladder[0]) * top), 0), top))


@numba.njit(cache=True)
def _half_extents(heading: float) -> tuple[float, float]:
    """Half length along x and half width along y [m] of the axis-aligned box around a vehicle
    body rotated by ``heading`` rad (a lane change tilts it: the box covers the corners)."""
    c, s = abs(cos(heading)), abs(sin(heading))
    return LENGTH / 2 * c + WIDTH / 2 * s, LENGTH / 2 * s + WIDTH / 2 * c


@numba.njit(cache=True)
def _set_action(
    i: int,
    action: int,
    target_y: np.ndarray,
    target_speed: np.ndarray,
    speed_step: np.ndarray,
    candidate_y: np.ndarray,
    candidate_speed: np.ndarray,
    repeat_actions: bool,
) -> None:
    """Predict AV ``i`` under meta-action ``action``: its target lane centre [m], target speed [m/s]
    and, with ``repeat_actions``, the speed change repeated at each policy step of the horizon."""
    target_y[i], target_speed[i] = candidate_y[i, action], candidate_speed[i, action]
    speed_step[i] = SPEED_STEP[action] if repeat_actions else 0


@numba.njit(cache=True)
def supervise_arrays(
    x: np.ndarray,
    y: np.ndarray,
    h: np.ndarray,
    v: np.ndarray,
    target_y: np.ndarray,
    target_speed: np.ndarray,
    is_hdv: np.ndarray,
    delta: np.ndarray,
    crashed: np.ndarray,
    collidable: np.ndarray,
    candidate_y: np.ndarray,
    candidate_speed: np.ndarray,
    available: np.ndarray,
    proposed: np.ndarray,
    frames: int,
    dt: float,
    lane_width: float,
    n_lanes: int,
    headway_time: float,
    min_gap: float,
    ladder: np.ndarray,
    frames_per_step: int,
    repeat_actions: bool,
) -> tuple[np.ndarray, np.ndarray]:
    """The supervisor on arrays (AVs first). Returns the executed actions and each AV's room [m]
    under them (NaN for AVs not served: those past the road end).

    :param candidate_y: (n_avs, 5) target lane centre y [m] of each AV under each meta-action
    :param candidate_speed: (n_avs, 5) target speed [m/s] under each meta-action
    :param available: (n_avs, 5) the action mask
    :param proposed: (n_avs,) the policy's meta-actions
    """
    n_avs = proposed.size
    executed = proposed.copy()
    rooms = np.full(n_avs, np.nan)
    target_y, target_speed = target_y.copy(), target_speed.copy()
    speed_step = np.zeros(x.size, dtype=np.int64)
    margin = np.empty(n_avs)
    for i in range(n_avs):
        _set_action(i, proposed[i], target_y, target_speed, speed_step, candidate_y, candidate_speed, repeat_actions)
        lane = min(max(int(np.floor(y[i] / lane_width + 0.5)), 0), n_lanes - 1)
        front = _leader(i, lane * lane_width, x, y, lane_width)
        margin[i] = (x[front] - x[i] if front >= 0 else NO_LEADER_GAP) - v[i] * headway_time
    order = np.argsort(margin, kind="mergesort")
    # the road predicted under the AVs' current actions, shared by every AV's room until one changes
    path = _predict(
        x,
        y,
        h,
        v,
        target_y,
        target_speed,
        is_hdv,
        delta,
        crashed,
        frames,
        dt,
        lane_width,
        n_lanes,
        speed_step,
        ladder,
        frames_per_step,
        -1,
        collidable,
        -np.inf,
    )[0]
    for _ in range(PASSES):
        changed = False
        for i in order:
            if not collidable[i]:
                continue
            current = executed[i]
            room = _room(i, path, collidable, dt)
            if room < min_gap:
                best, best_room, best_path = current, room, path
                for a in PREFERENCE:
                    if available[i, a] and a != current:
                        _set_action(i, a, target_y, target_speed, speed_step, candidate_y, candidate_speed, repeat_actions)
                        # stopped once it cannot beat the best: such a candidate is never chosen
                        candidate_path, candidate_room = _predict(
                            x,
                            y,
                            h,
                            v,
                            target_y,
                            target_speed,
                            is_hdv,
                            delta,
                            crashed,
                            frames,
                            dt,
                            lane_width,
                            n_lanes,
                            speed_step,
                            ladder,
                            frames_per_step,
                            i,
                            collidable,
                            best_room,
                        )
                        if candidate_room > best_room:
                            best, best_room, best_path = a, candidate_room, candidate_path
                changed = changed or best != current
                executed[i], room, path = best, best_room, best_path
                _set_action(i, best, target_y, target_speed, speed_step, candidate_y, candidate_speed, repeat_actions)
            rooms[i] = room
        if not changed:
            break  # another pass would see the same actions and find the same rooms
    # Joint fallback: the passes serve one AV at a time against the others' current actions, so two
    # AVs whose lane changes conflict can each find every option unsafe and end up crossing each
    # other. The AVs still short of room after a lane change keep their lanes (IDLE) together,
    # if that leaves every served AV more room than before.
    stuck = np.zeros(n_avs, dtype=np.bool_)
    for i in order:
        stuck[i] = collidable[i] and rooms[i] < min_gap and (executed[i] == LANE_LEFT or executed[i] == LANE_RIGHT)
    if stuck.any():
        trial_y, trial_speed, trial_step = target_y.copy(), target_speed.copy(), speed_step.copy()
        for i in range(n_avs):
            if stuck[i]:
                _set_action(i, IDLE, trial_y, trial_speed, trial_step, candidate_y, candidate_speed, repeat_actions)
        trial_path = _predict(
            x,
            y,
            h,
            v,
            trial_y,
            trial_speed,
            is_hdv,
            delta,
            crashed,
            frames,
            dt,
            lane_width,
            n_lanes,
            trial_step,
            ladder,
            frames_per_step,
            -1,
            collidable,
            -np.inf,
        )[0]
        trial_rooms = rooms.copy()
        before, after = np.inf, np.inf
        for i in order:
            if collidable[i]:
                trial_rooms[i] = _room(i, trial_path, collidable, dt)
                before, after = min(before, rooms[i]), min(after, trial_rooms[i])
        if after > before:
            for i in range(n_avs):
                if stuck[i]:
                    executed[i] = IDLE
            rooms = trial_rooms
    return executed, rooms


@numba.njit(cache=True)
def candidate_targets(
    x: np.ndarray,
    y: np.ndarray,
    v: np.ndarray,
    target_lane: np.ndarray,
    target_speed: np.ndarray,
    ladder: np.ndarray,
    n_lanes: int,
    lane_width: float,
    road_length: float,
) -> tuple[np.ndarray, np.ndarray]:
    """(n_avs, 5) target lane centre y [m] and (n_avs, 5) target speed [m/s] of each AV under each
    meta-action, as highway-env's ``MDPVehicle.act`` would set them (LANE_LEFT 0, IDLE 1,
    LANE_RIGHT 2, FASTER 3, SLOWER 4; a lane change to a lane not reachable from the AV's position
    and a speed change past the ``ladder`` [m/s] change nothing). Arguments: the AVs' rows."""
    n_avs, top = x.size, ladder.size - 1
    candidate_y, candidate_speed = np.empty((n_avs, 5)), np.empty((n_avs, 5))
    for i in range(n_avs):
        lane = int(target_lane[i])
        candidate_y[i, :] = lane * lane_width
        for action, side in ((LANE_LEFT, -1), (LANE_RIGHT, 1)):
            other = min(max(lane + side, 0), n_lanes - 1)  # StraightLane.is_reachable_from:
            if abs(y[i] - other * lane_width) <= 2 * lane_width and 0 <= x[i] < road_length + LANE_VEHICLE_LENGTH:
                candidate_y[i, action] = other * lane_width
        candidate_speed[i, :] = target_speed[i]
        index = _speed_index(v[i], ladder)
        candidate_speed[i, 3] = ladder[min(index + 1, top)]
        candidate_speed[i, 4] = ladder[max(index - 1, 0)]
    return candidate_y, candidate_speed


def supervise(
    vehicles: list[Vehicle], n_avs: int, proposed: np.ndarray, available: np.ndarray, config: dict[str, Any]
) -> tuple[np.ndarray, np.ndarray]:
    """Executed meta-actions (n_avs,) and each AV's predicted room [m] (see the module doc).

    :param vehicles: the road's vehicles, the ``n_avs`` AVs first
    :param proposed: (n_avs,) the policy's meta-actions
    :param available: (n_avs, 5) bool action mask
    :param config: the scenario config (lanes, frequencies, ``supervisor_horizon`` [s],
        ``supervisor_min_gap`` [m], ``headway_time`` [s])
    """
    n_lanes, lane_width = config["lanes_count"], float(config["lane_width"])
    speed_limit = float(config["speed_limit"])
    # one row per vehicle; the columns, in order: x, y [m], heading [rad], speed [m/s], target lane,
    # target speed [m/s] (an HDV's capped by the speed limit, as its IDM does), is HDV, IDM exponent,
    # crashed, collidable
    state = np.array(
        [
            (
                *xy(v.position),
                v.heading,
                v.speed,
                v.target_lane_index[2],
                min(max(v.target_speed, 0.0), speed_limit) if isinstance(v, IDMVehicle) else v.target_speed,
                isinstance(v, IDMVehicle),
                getattr(v, "DELTA", 4.0),
                v.crashed,
                v.collidable,
            )
            for v in vehicles
        ],
        dtype=np.float64,
    ).reshape(-1, 10)
    x, y, h, v, target_lane, target_speed, is_hdv, delta, crashed, collidable = (
        np.ascontiguousarray(column) for column in state.T
    )
    ladder = np.asarray(config["target_speeds"], dtype=np.float64)
    candidate_y, candidate_speed = candidate_targets(
        x[:n_avs],
        y[:n_avs],
        v[:n_avs],
        target_lane[:n_avs],
        target_speed[:n_avs],
        ladder,
        n_lanes,
        lane_width,
        float(config["road_length"]),
    )
    frames = max(int(round(config["supervisor_horizon"] * config["simulation_frequency"])), 1)
    return supervise_arrays(
        x,
        y,
        h,
        v,
        target_lane * lane_width,
        target_speed,
        is_hdv > 0,
        delta,
        crashed > 0,
        collidable > 0,
        candidate_y,
        candidate_speed,
        np.asarray(available, dtype=np.bool_),
        np.asarray(proposed, dtype=np.int64),
        frames,
        1.0 / config["simulation_frequency"],
        lane_width,
        n_lanes,
        float(config["headway_time"]),
        float(config["supervisor_min_gap"]),
        ladder,
        max(config["simulation_frequency"] // config["policy_frequency"], 1),
        bool(config["supervisor_repeat_actions"]),
    )
