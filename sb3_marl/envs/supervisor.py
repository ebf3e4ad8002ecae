"""The priority-based safety supervisor of the authors' MA2C (Chen et al. 2021, arXiv 2105.05701).

Every policy step, before the AVs act, the supervisor serves the AVs on the road one by one in
priority order: the smallest headway margin first (gap to the leader in the AV's lane [m] minus
speed [m/s] × ``headway_time`` [s]; equal margins: the lower AV index first, so runs stay
reproducible without drawing random numbers). For the AV being served it predicts the next
``supervisor_horizon`` s of the whole road, frame by frame at ``simulation_frequency`` Hz:

- every vehicle with the road's own equations (:func:`sb3_marl.envs.dynamics.drive`: highway-env's
  controllers, the HDVs' IDM and MOBIL lane changes with their timers and abort rule, the
  kinematic bicycle model and the lane update), on a copy of the road's state array (the kernel's
  layout): the prediction is exact for the HDVs as
  long as the AVs drive as predicted; collisions and the road end are not simulated (the room
  measures how close the vehicles come);
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

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import numba
import numpy as np

from sb3_marl.envs.drivers import lane_distance, lane_occupancy, leader
from sb3_marl.envs.dynamics import drive
from sb3_marl.envs.kernel import (
    COLLIDABLE,
    HEADING,
    IS_OBSTACLE,
    LANE,
    LENGTH,
    OBSTACLE_LENGTH,
    SPEED,
    TARGET_LANE,
    TARGET_SPEED,
    WIDTH,
    X,
    Y,
    cos,
    sin,
)
from sb3_marl.envs.lanes import closest_lane, follow, local_coordinates, on_lane
from sb3_marl.envs.meta_actions import meta_action_targets, speed_index
from sb3_marl.envs.road import highway_lanes

#: Version of the supervisor's decisions; evaluations record it, and ``sb3-marl benchmark evaluate``
#: re-evaluates trials evaluated under another (history in CHANGELOG.md; 3: the road's own equations).
VERSION = 3
NO_LEADER_GAP = 1e6  # [m], headway of an AV without leader (priority only)
#: Replacement candidates in tie order: IDLE, SLOWER, FASTER, LANE_LEFT, LANE_RIGHT
#: (highway-env's meta-action indices).
PREFERENCE = np.array([1, 4, 3, 0, 2], dtype=np.int64)
#: Speed-index change of each meta-action (FASTER +1, SLOWER -1) when actions repeat over the horizon.
SPEED_STEP = np.array([0, 0, 0, 1, -1], dtype=np.int64)
LANE_LEFT, IDLE, LANE_RIGHT = 0, 1, 2
#: Passes over the AVs in priority order (the second checks against the first pass's final actions).
PASSES = 2
#: [s] the time an AV is given to leave a lane an obstacle ends (see :func:`_dead_end_margin`)
LEAVE_TIME = 2.5


class Horizon(NamedTuple):
    """The road and the prediction's time grid (compiled code takes it as one argument)."""

    lanes: np.ndarray  # the road's lane table (sb3_marl.envs.lanes)
    road_end: float  # [m] x past which vehicles leave the road
    speed_limit: float  # [m/s]
    dt: float  # [s] one frame
    frames: int  # frames predicted
    frames_per_step: int  # frames of one policy step
    ladder: np.ndarray  # [m/s] the AVs' target speeds (MDPVehicle.target_speeds)

    @classmethod
    def from_config(cls, config: dict[str, Any], lanes: np.ndarray | None = None, road_end: float | None = None) -> Horizon:
        """The road and time grid of a scenario config (frequencies [Hz], ``supervisor_horizon`` [s]);
        the road is ``lanes`` and ``road_end`` [m], by default the lane-change highway of the config
        (:func:`~sb3_marl.envs.road.highway_lanes`, ``road_length``)."""
        return cls(
            lanes=highway_lanes(config) if lanes is None else lanes,
            road_end=float(config["road_length"] if road_end is None else road_end),
            speed_limit=float(config["speed_limit"]),
            dt=1.0 / config["simulation_frequency"],
            frames=max(int(round(config["supervisor_horizon"] * config["simulation_frequency"])), 1),
            frames_per_step=max(config["simulation_frequency"] // config["policy_frequency"], 1),
            ladder=np.asarray(config["target_speeds"], dtype=np.float64),
        )


@numba.njit(cache=True)
def _predict(
    state0: np.ndarray, horizon: Horizon, speed_step: np.ndarray, ego: int, collidable: np.ndarray, floor: float
) -> tuple[np.ndarray, float]:
    """(frames, 4, n) x, y [m], heading [rad] and speed [m/s] of every vehicle after each frame of
    the road driven from ``state0`` (the kernel's layout, the AVs' targets set), and the room [m] of
    vehicle ``ego`` along it (see :func:`_room`; inf for ``ego`` -1). The prediction stops as soon
    as that room is at most ``floor`` m (it can only shrink): the rest of the path is then unset.

    ``speed_step`` (+1 FASTER, -1 SLOWER, 0 otherwise, per AV) repeats a speed change at every
    policy step of the horizon, as ``MDPVehicle.act`` would on the speed ladder: the AV keeps its
    action over the horizon."""
    state = state0.copy()
    n = state.shape[0]
    path = np.empty((horizon.frames, 4, n))
    room = np.inf
    ladder = horizon.ladder
    top = ladder.size - 1
    for frame in range(horizon.frames):
        if frame > 0 and frame % horizon.frames_per_step == 0:
            for k in range(speed_step.size):
                if speed_step[k] != 0:
                    index = min(max(speed_index(state[k, SPEED], ladder) + speed_step[k], 0), top)
                    state[k, TARGET_SPEED] = ladder[index]
        drive(state, horizon.dt, horizon.lanes, horizon.speed_limit)
        path[frame, 0], path[frame, 1] = state[:, X], state[:, Y]
        path[frame, 2], path[frame, 3] = state[:, HEADING], state[:, SPEED]
        if ego >= 0:
            room = min(
                room, _frame_room(ego, path[frame, 0], path[frame, 1], path[frame, 2], path[frame, 3], collidable, horizon.dt)
            )
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
def _half_extents(heading: float) -> tuple[float, float]:
    """Half length along x and half width along y [m] of the axis-aligned box around a vehicle
    body rotated by ``heading`` rad (a lane change tilts it: the box covers the corners)."""
    c, s = abs(cos(heading)), abs(sin(heading))
    return LENGTH / 2 * c + WIDTH / 2 * s, LENGTH / 2 * s + WIDTH / 2 * c


@numba.njit(cache=True)
def _set_action(
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


@numba.njit(cache=True)
def _counted(state0: np.ndarray, ego: int, n_avs: int, collidable: np.ndarray, rear_avs: bool) -> np.ndarray:
    """The vehicles the room of AV ``ego`` counts: the collidable ones, without (unless
    ``rear_avs``) the AVs behind it in its own lane, which are served themselves and may brake
    for it (counted, they make braking look worse than holding the speed)."""
    counted = collidable.copy()
    if not rear_avs:
        for j in range(n_avs):
            if j != ego and state0[j, LANE] == state0[ego, LANE] and state0[j, X] < state0[ego, X]:
                counted[j] = False
    return counted


@numba.njit(cache=True)
def supervise_arrays(
    state0: np.ndarray,
    candidate_lane: np.ndarray,
    candidate_speed: np.ndarray,
    available: np.ndarray,
    proposed: np.ndarray,
    priority: np.ndarray,
    horizon: Horizon,
    min_gap: float,
    repeat_actions: bool,
    rear_avs: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """The supervisor on the road's state array (the kernel's layout, AVs first). Returns the
    executed actions and each AV's room [m] under them (NaN for AVs not served: past the road end).

    :param candidate_lane: (n_avs, 5) target lane of each AV under each meta-action
    :param candidate_speed: (n_avs, 5) target speed [m/s] under each meta-action
    :param available: (n_avs, 5) the action mask
    :param proposed: (n_avs,) the policy's meta-actions
    :param priority: (n_avs,) the order of service, the smallest first (equal: the lower index first)
    :param min_gap: [m] the smallest room an action may leave
    :param rear_avs: whether an AV's room counts the AVs behind it in its lane (see
        :func:`_counted`)
    """
    n_avs = proposed.size
    executed = proposed.copy()
    rooms = np.full(n_avs, np.nan)
    state = state0.copy()  # the AVs' targets under the actions being checked
    collidable = state[:, COLLIDABLE] > 0
    dt = horizon.dt
    speed_step = np.zeros(n_avs, dtype=np.int64)
    for i in range(n_avs):
        _set_action(state, i, proposed[i], speed_step, candidate_lane, candidate_speed, repeat_actions)
    order = np.argsort(priority, kind="mergesort")
    # the road predicted under the AVs' current actions, shared by every AV's room until one changes
    path = _predict(state, horizon, speed_step, -1, collidable, -np.inf)[0]
    obstacles = np.flatnonzero(state0[:, IS_OBSTACLE] > 0)
    for _ in range(PASSES):
        changed = False
        for i in order:
            if not collidable[i]:
                continue
            counted = _counted(state0, i, n_avs, collidable, rear_avs)
            current = executed[i]
            room = _room(i, path, counted, dt)
            dead_end = _dead_end_margin(state, i, path, horizon.lanes, obstacles)
            if room < min_gap or dead_end < 0:
                best, best_room, best_dead_end, best_path = current, room, dead_end, path
                for a in PREFERENCE:
                    if available[i, a] and a != current:
                        _set_action(state, i, a, speed_step, candidate_lane, candidate_speed, repeat_actions)
                        # stopped once it cannot beat the best room: such a candidate is never
                        # chosen (with a dead end ahead, every candidate is predicted in full)
                        floor = best_room if obstacles.size == 0 else -np.inf
                        candidate_path, candidate_room = _predict(state, horizon, speed_step, i, counted, floor)
                        candidate_dead_end = _dead_end_margin(state, i, candidate_path, horizon.lanes, obstacles)
                        if _better(candidate_room, candidate_dead_end, best_room, best_dead_end, min_gap):
                            best, best_room, best_dead_end, best_path = a, candidate_room, candidate_dead_end, candidate_path
                changed = changed or best != current
                executed[i], room, path = best, best_room, best_path
                _set_action(state, i, best, speed_step, candidate_lane, candidate_speed, repeat_actions)
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
        trial, trial_step = state.copy(), speed_step.copy()
        for i in range(n_avs):
            if stuck[i]:
                _set_action(trial, i, IDLE, trial_step, candidate_lane, candidate_speed, repeat_actions)
        trial_path = _predict(trial, horizon, trial_step, -1, collidable, -np.inf)[0]
        trial_rooms = rooms.copy()
        before, after = np.inf, np.inf
        for i in order:
            if collidable[i]:
                trial_rooms[i] = _room(i, trial_path, _counted(state0, i, n_avs, collidable, rear_avs), dt)
                before, after = min(before, rooms[i]), min(after, trial_rooms[i])
        if after > before:
            for i in range(n_avs):
                if stuck[i]:
                    executed[i] = IDLE
            rooms = trial_rooms
    return executed, rooms


@numba.njit(cache=True)
def _dead_end_margin(state: np.ndarray, ego: int, path: np.ndarray, lanes: np.ndarray, obstacles: np.ndarray) -> float:
    """[m] How much room AV ``ego`` has left, at the end of the predicted ``path``, to leave a lane
    that an obstacle ends (the merging lane): the gap to the obstacle ahead on the lane it keeps,
    minus the distance it covers in :data:`LEAVE_TIME` at its speed; inf when no obstacle ends its
    lane or it is changing lanes. Its meta-actions cannot stop it (the lowest target speed is 10
    m/s), so this is how late it may still merge."""
    if obstacles.size == 0:
        return np.inf
    last = path.shape[0] - 1
    x, y, v = path[last, 0, ego], path[last, 1, ego], path[last, 3, ego]
    lane = closest_lane(lanes, x, y, path[last, 2, ego])
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


@numba.njit(cache=True)
def _better(room: float, dead_end: float, best_room: float, best_dead_end: float, min_gap: float) -> bool:
    """Whether a candidate action beats the best so far: first the actions with room and a way off
    a dead-end lane (the larger room first), then those with room (the larger dead-end margin
    first), then the larger room."""
    tier = 2 if room >= min_gap and dead_end >= 0 else (1 if room >= min_gap else 0)
    best_tier = 2 if best_room >= min_gap and best_dead_end >= 0 else (1 if best_room >= min_gap else 0)
    if tier != best_tier:
        return tier > best_tier
    return dead_end > best_dead_end if tier == 1 else room > best_room


@numba.njit(cache=True)
def headway_margins(state: np.ndarray, n_avs: int, lanes: np.ndarray, headway_time: float) -> np.ndarray:
    """(n_avs,) each AV's headway margin [m]: the gap to its leader in its lane (:data:`NO_LEADER_GAP`
    without one) minus its speed [m/s] × ``headway_time`` [s] (the lane change's priority)."""
    occupancy = lane_occupancy(state, lanes)
    margin = np.empty(n_avs)
    for i in range(n_avs):
        front = leader(state, lanes, occupancy, i)
        gap = lane_distance(state, lanes, i, front) if front >= 0 else NO_LEADER_GAP
        margin[i] = gap - state[i, SPEED] * headway_time
    return margin


@dataclass(frozen=True)
class Supervisor:
    """The supervisor of one scenario config (see the module doc); the env builds it at each reset.

    :param horizon: the road and the prediction's time grid
    :param headway_time: [s] of the priority's headway margin (``headway_time``)
    :param min_gap: [m] the smallest predicted room an action may leave (``supervisor_min_gap``)
    :param repeat_actions: every AV repeats its action at each policy step of the horizon
        (``supervisor_repeat_actions``)
    :param rear_avs: protect each AV from the AVs behind it too (``supervisor_rear_avs``)
    :param priorities: (state, n_avs, supervisor) -> (n_avs,) the order of service, the smallest
        first; by default the headway margin (:func:`headway_margins`)
    """

    horizon: Horizon
    headway_time: float
    min_gap: float
    repeat_actions: bool
    rear_avs: bool
    priorities: Callable[[np.ndarray, int, Supervisor], np.ndarray] | None = None

    @classmethod
    def from_config(
        cls,
        config: dict[str, Any],
        lanes: np.ndarray | None = None,
        road_end: float | None = None,
        priorities: Callable[[np.ndarray, int, Supervisor], np.ndarray] | None = None,
    ) -> Supervisor:
        """The supervisor of ``config`` on the road ``lanes`` (see :meth:`Horizon.from_config`)."""
        return cls(
            Horizon.from_config(config, lanes, road_end),
            float(config["headway_time"]),
            float(config["supervisor_min_gap"]),
            bool(config["supervisor_repeat_actions"]),
            bool(config["supervisor_rear_avs"]),
            priorities,
        )

    def __call__(
        self, state: np.ndarray, n_avs: int, proposed: np.ndarray, available: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Executed meta-actions (n_avs,) and each AV's predicted room [m].

        :param state: the road's state array (:mod:`~sb3_marl.envs.kernel` layout), the ``n_avs`` AVs
            first; not modified
        :param proposed: (n_avs,) the policy's meta-actions
        :param available: (n_avs, 5) bool action mask
        """
        horizon = self.horizon
        candidate_lane, candidate_speed = meta_action_targets(state, n_avs, horizon.lanes, horizon.ladder)
        if self.priorities is None:
            priority = headway_margins(state, n_avs, horizon.lanes, self.headway_time)
        else:
            priority = self.priorities(state, n_avs, self)
        return supervise_arrays(
            state,
            candidate_lane,
            candidate_speed,
            np.asarray(available, dtype=np.bool_),
            np.asarray(proposed, dtype=np.int64),
            priority,
            horizon,
            self.min_gap,
            self.repeat_actions,
            self.rear_avs,
        )
