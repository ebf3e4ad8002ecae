"""The safety supervisor's predictions and the room they leave: the road driven ahead with its own
equations (:func:`predict`), the smallest bumper-to-bumper gap of a vehicle along it (:func:`path_room`)
and how late an AV may still leave a lane an obstacle ends (:func:`dead_end_margin`), on the
road and time grid of a :class:`Horizon`; an AV's options set into the predicted state
(:func:`set_action`, :func:`set_brake`), the vehicles each AV's room counts (:func:`counted_by`)
and MOBIL's safety check of a cut-in (:func:`unsafe_cut_ins`). Units: m, m/s, rad, s.
"""

from __future__ import annotations

from typing import Any, NamedTuple, cast

import numpy as np

from sb3_marl.sim.drivers import idm
from sb3_marl.sim.dynamics import drive
from sb3_marl.sim.kernel import (
    HEADING,
    IS_HDV,
    LANE,
    LENGTH,
    MAX_BRAKING_IMPOSED,
    NO_VEHICLE,
    OBSTACLE_LENGTH,
    PRESENT,
    SPEED,
    TARGET_LANE,
    TARGET_SPEED,
    WIDTH,
    X,
    Y,
    cos,
    jit,
    sin,
)
from sb3_marl.sim.lanes import NEXT_COUNT, NEXT_FIRST, closest_lane, follow, local_coordinates, on_lane
from sb3_marl.sim.meta_actions import speed_index
from sb3_marl.sim.road import highway_lanes

#: [s] the time an AV is given to leave a lane an obstacle ends (see :func:`dead_end_margin`)
LEAVE_TIME = 2.5
#: Rows of a predicted path's frame (:func:`predict`): x, y [m], heading [rad], speed [m/s], the
#: velocity's x and y [m/s], and the half length along x and half width along y [m] of the
#: axis-aligned box around the body.
PATH_X, PATH_Y, PATH_HEADING, PATH_SPEED, VX, VY, HALF_X, HALF_Y = range(8)
PATH_ROWS = 8


class Horizon(NamedTuple):
    """The road and the prediction's time grid (compiled code takes it as one argument)."""

    lanes: np.ndarray  # the road's lane table (sb3_marl.sim.lanes)
    road_end: float  # [m] x past which vehicles leave the road
    speed_limit: float  # [m/s]
    dt: float  # [s] one frame
    frames: int  # frames predicted, each of ``stride`` frames (stride × dt s)
    frames_per_step: int  # frames of one policy step
    ladder: np.ndarray  # [m/s] the AVs' target speeds (MDPVehicle.target_speeds)
    stride: int  # simulated frames per predicted frame: 1, or a policy step's (supervisor_version 6)

    @classmethod
    def from_config(
        cls, config: dict[str, Any], lanes: np.ndarray | None = None, road_end: float | None = None, stride: int = 1
    ) -> Horizon:
        """The road and time grid of a scenario config (frequencies [Hz], ``supervisor_horizon`` [s]);
        the road is ``lanes`` and ``road_end`` [m], by default the lane-change highway of the config
        (:func:`~sb3_marl.sim.road.highway_lanes`, ``road_length``); the prediction takes ``stride``
        simulated frames at a time (0: a policy step's)."""
        frames_per_step = max(config["simulation_frequency"] // config["policy_frequency"], 1)
        stride = stride or frames_per_step
        return cls(
            lanes=highway_lanes(config) if lanes is None else lanes,
            road_end=float(config["road_length"] if road_end is None else road_end),
            speed_limit=float(config["speed_limit"]),
            dt=1.0 / config["simulation_frequency"],
            frames=max(int(round(config["supervisor_horizon"] * config["simulation_frequency"] / stride)), 1),
            frames_per_step=frames_per_step,
            ladder=np.asarray(config["target_speeds"], dtype=np.float64),
            stride=stride,
        )


@jit
def predict(
    state0: np.ndarray, horizon: Horizon, speed_step: np.ndarray, ego: int, collidable: np.ndarray, floor: float
) -> tuple[np.ndarray, float]:
    """(frames, :data:`PATH_ROWS`, n) every vehicle after each predicted frame (``horizon.stride``
    simulated frames in one step of stride × dt s) of the road driven from
    ``state0`` (the kernel's layout, the AVs' targets set), and the room [m] of
    vehicle ``ego`` along it (see :func:`path_room`; inf for ``ego`` -1). The prediction stops as soon
    as that room is at most ``floor`` m (it can only shrink): the rest of the path is then unset.

    ``speed_step`` (+1 FASTER, -1 SLOWER, 0 otherwise, per AV) repeats a speed change at every
    policy step of the horizon, as ``MDPVehicle.act`` would on the speed ladder: the AV keeps its
    action over the horizon."""
    state = state0.copy()
    n = state.shape[0]
    path = np.empty((horizon.frames, PATH_ROWS, n))
    room = np.inf
    ladder = horizon.ladder
    top = ladder.size - 1
    dt, per_step = horizon.dt * horizon.stride, max(horizon.frames_per_step // horizon.stride, 1)
    for frame in range(horizon.frames):
        if frame > 0 and frame % per_step == 0:
            for k in range(speed_step.size):
                if speed_step[k] != 0:
                    index = min(max(speed_index(state[k, SPEED], ladder) + speed_step[k], 0), top)
                    state[k, TARGET_SPEED] = ladder[index]
        drive(state, dt, horizon.lanes, horizon.speed_limit)
        _record(path[frame], state)
        if ego >= 0:
            room = min(room, frame_room(ego, path[frame], collidable, horizon.dt))
            if room <= floor:
                break
    return path, room


@jit
def _record(frame: np.ndarray, state: np.ndarray) -> None:
    """One frame of a path (:data:`PATH_ROWS`, n) from the state array: the trigonometry of every
    vehicle's heading is taken once per frame, not once per pair of vehicles."""
    for k in range(state.shape[0]):
        heading, speed = state[k, HEADING], state[k, SPEED]
        c, s = cos(heading), sin(heading)
        frame[PATH_X, k], frame[PATH_Y, k] = state[k, X], state[k, Y]
        frame[PATH_HEADING, k], frame[PATH_SPEED, k] = heading, speed
        frame[VX, k], frame[VY, k] = speed * c, speed * s
        # the axis-aligned box around the body rotated by the heading (a lane change tilts it)
        frame[HALF_X, k] = LENGTH / 2 * abs(c) + WIDTH / 2 * abs(s)
        frame[HALF_Y, k] = LENGTH / 2 * abs(s) + WIDTH / 2 * abs(c)


@jit
def path_room(ego: int, path: np.ndarray, collidable: np.ndarray, dt: float) -> float:
    """Smallest bumper-to-bumper gap [m] along a predicted ``path`` (see :func:`predict`) between
    vehicle ``ego`` and any collidable vehicle overlapping it laterally (negative: a collision)."""
    room = np.inf
    for frame in range(path.shape[0]):
        room = min(room, frame_room(ego, path[frame], collidable, dt))
    return room


@jit
def frame_room(ego: int, frame: np.ndarray, collidable: np.ndarray, dt: float) -> float:
    """:func:`path_room` of one frame of a path."""
    room = np.inf
    x, y, vx, vy = frame[PATH_X], frame[PATH_Y], frame[VX], frame[VY]
    for j in range(x.size):
        if j != ego and collidable[j]:
            # highway-env flags a collision when the bodies would meet within the next frame
            # (each moved by its velocity × dt): the gaps shrink by the closing speed × dt
            dx, dy = x[j] - x[ego], y[j] - y[ego]
            closing_y = (vy[ego] - vy[j]) * np.sign(dy)
            if abs(dy) - max(closing_y, 0.0) * dt < frame[HALF_Y, ego] + frame[HALF_Y, j]:
                closing_x = (vx[ego] - vx[j]) * np.sign(dx)
                room = min(room, abs(dx) - frame[HALF_X, ego] - frame[HALF_X, j] - max(closing_x, 0.0) * dt)
    return room


@jit
def dead_end_margin(state: np.ndarray, ego: int, path: np.ndarray, lanes: np.ndarray, obstacles: np.ndarray) -> float:
    """[m] How much room AV ``ego`` has left, at the end of the predicted ``path``, to leave a lane
    that an obstacle ends (the merging lane): the gap to the obstacle ahead on the lane it keeps,
    minus the distance it covers in :data:`LEAVE_TIME` at its speed; inf when no obstacle ends its
    lane or it is changing lanes. Its meta-actions cannot stop it (the lowest target speed is 10
    m/s), so this is how late it may still merge."""
    if obstacles.size == 0:
        return np.inf
    last = path.shape[0] - 1
    x, y, v = path[last, PATH_X, ego], path[last, PATH_Y, ego], path[last, PATH_SPEED, ego]
    lane = closest_lane(lanes, x, y, path[last, PATH_HEADING, ego])
    if follow(lanes, int(state[ego, TARGET_LANE]), x, y) != lane:
        return np.inf
    s = local_coordinates(lanes, lane, x, y)[0]
    margin = np.inf
    for j in obstacles:
        if on_lane(lanes, lane, state[j, X], state[j, Y], 1.0):
            gap = local_coordinates(lanes, lane, state[j, X], state[j, Y])[0] - s - (LENGTH + OBSTACLE_LENGTH) / 2
            if gap > -LENGTH:
                margin = min(margin, gap - v * LEAVE_TIME)
    return margin


#: Replacement candidates in tie order: IDLE, SLOWER, FASTER, LANE_LEFT, LANE_RIGHT
#: (highway-env's meta-action indices).
PREFERENCE = np.array([1, 4, 3, 0, 2], dtype=np.int64)
#: Speed-index change of each meta-action (FASTER +1, SLOWER -1) when actions repeat over the horizon.
SPEED_STEP = np.array([0, 0, 0, 1, -1], dtype=np.int64)
#: highway-env's meta-action indices as int64 (see :data:`~sb3_marl.sim.kernel.NO_VEHICLE`)
LANE_LEFT, IDLE, LANE_RIGHT, SLOWER = (cast(int, np.int64(action)) for action in (0, 1, 2, 4))
#: :func:`counted_by`'s ``rear_avs`` off, as a typed bool (a literal False compiles it again)
AHEAD_ONLY = cast(bool, np.bool_(False))


@jit
def set_action(
    state: np.ndarray,
    i: int,
    action: int,
    speed_step: np.ndarray,
    candidate_lane: np.ndarray,
    candidate_speed: np.ndarray,
    repeat_actions: bool,
) -> None:
    """Predict AV ``i`` under meta-action ``action``: its target lane and target speed [m/s] in
    ``state`` and, with ``repeat_actions``, the speed change repeated at each policy step."""
    state[i, TARGET_LANE], state[i, TARGET_SPEED] = candidate_lane[i, action], candidate_speed[i, action]
    speed_step[i] = SPEED_STEP[action] if repeat_actions else 0


@jit
def set_brake(state: np.ndarray, i: int, speed_step: np.ndarray, candidate_lane: np.ndarray) -> None:
    """Predict AV ``i`` under the emergency brake: IDLE's target lane, target speed 0 m/s."""
    state[i, TARGET_LANE], state[i, TARGET_SPEED] = candidate_lane[i, IDLE], 0.0
    speed_step[i] = 0


@jit
def counted_by(state0: np.ndarray, ego: int, n_avs: int, collidable: np.ndarray, rear_avs: bool) -> np.ndarray:
    """The vehicles the room of AV ``ego`` counts: the collidable ones, without (unless
    ``rear_avs``) the AVs behind it in its own lane, which are served themselves and may brake
    for it (counted, they make braking look worse than holding the speed)."""
    counted = collidable.copy()
    if not rear_avs:
        for j in range(n_avs):
            if j != ego and state0[j, LANE] == state0[ego, LANE] and state0[j, X] < state0[ego, X]:
                counted[j] = False
    return counted


@jit
def counted_by_all(state0: np.ndarray, n_avs: int, collidable: np.ndarray, rear_avs: bool) -> np.ndarray:
    """(n_avs, n_vehicles): row ``i`` the vehicles the room of AV ``i`` counts (:func:`counted_by`)."""
    counted = np.zeros((n_avs, collidable.size), dtype=np.bool_)
    for i in range(n_avs):
        counted[i] = counted_by(state0, i, n_avs, collidable, rear_avs)
    return counted


@jit
def av_rooms(path: np.ndarray, counted: np.ndarray, collidable: np.ndarray, dt: float) -> np.ndarray:
    """(n_avs,) each collidable AV's room [m] along the predicted road ``path`` (NaN for the others),
    counting the vehicles of its row of ``counted`` (:func:`counted_by_all`)."""
    rooms = np.full(counted.shape[0], np.nan)
    for i in range(rooms.size):
        if collidable[i]:
            rooms[i] = path_room(i, path, counted[i], dt)
    return rooms


@jit
def unsafe_cut_ins(
    state: np.ndarray, n_avs: int, lanes: np.ndarray, candidate_lane: np.ndarray, speed_limit: float
) -> np.ndarray:
    """(n_avs, 5) the meta-actions that take an AV into a lane (or on into the lane it is changing
    to) in front of an HDV that would then have to brake harder than its MOBIL safe braking
    [m/s²]: IDM's acceleration of the nearest HDV behind the AV on that lane, or on a lane leading
    into it (whose HDVs do not see the AV yet), with the AV as its leader (MOBIL's safety check)."""
    unsafe = np.zeros((n_avs, candidate_lane.shape[1]), dtype=np.bool_)
    for i in range(n_avs):
        for a in range(candidate_lane.shape[1]):
            lane = int(candidate_lane[i, a])
            if lane == int(state[i, LANE]):
                continue
            s_i = local_coordinates(lanes, lane, state[i, X], state[i, Y])[0]
            follower, s_follower = NO_VEHICLE, -np.inf
            for j in range(n_avs, state.shape[0]):
                if state[j, IS_HDV] <= 0 or state[j, PRESENT] <= 0:
                    continue
                own = int(state[j, LANE])
                first = int(lanes[own, NEXT_FIRST])
                if own != lane and not first <= lane < first + int(lanes[own, NEXT_COUNT]):
                    continue
                s_j = local_coordinates(lanes, lane, state[j, X], state[j, Y])[0]
                if s_follower < s_j < s_i:
                    follower, s_follower = j, s_j
            if follower >= 0:
                unsafe[i, a] = idm(state, lanes, follower, i, speed_limit) < -state[follower, MAX_BRAKING_IMPOSED]
    return unsafe
