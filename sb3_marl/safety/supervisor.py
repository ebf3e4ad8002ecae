"""The priority-based safety supervisor of the authors' MA2C (Chen et al. 2021, arXiv 2105.05701).

Every policy step, before the AVs act, the supervisor serves the AVs on the road one by one in
priority order: the smallest headway margin first (gap to the leader in the AV's lane [m] minus
speed [m/s] × ``headway_time`` [s]; :func:`headway_margins`; the merge serves its merging lane
first, the merge's own order in the scenario's compiled step; equal priorities: the lower AV index first, so runs
stay reproducible without drawing random numbers). For the AV being served it predicts the next
``supervisor_horizon`` s of the whole road, frame by frame at ``simulation_frequency`` Hz (from
``supervisor_version`` 6, the default: a policy step at a time, at ``policy_frequency`` Hz, the
same equations on frames of 1 / policy_frequency s; :mod:`sb3_marl.safety.rooms`):

- every vehicle with the road's own equations (:func:`sb3_marl.sim.dynamics.drive`: highway-env's
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
distance the two vehicles close within the next simulated frame, so a negative room is a predicted
collision, with a little to spare. If the action's room is below ``supervisor_min_gap`` m
(default 2 m), it is replaced by the action available to the AV (the env's action mask) with the
largest room, ties in the order IDLE, SLOWER, FASTER, LANE_LEFT, LANE_RIGHT. The AVs are served
in two passes (:data:`PASSES`): the second re-checks each AV against the actions the others ended
with in the first (an AV served early was checked against proposals that may have been replaced
since). Served one at a time, two AVs whose lane changes conflict can still each find every option
unsafe and cross each other; a joint fallback then makes the AVs left short of room after a lane
change keep their lanes together (IDLE), when that leaves every AV more room. With
``supervisor_joint_search`` (on by default on the merge), the AVs still short of room then have
their options searched in pairs with every other AV's, the whole road predicted for each pair
(:func:`~sb3_marl.safety.joint_search.search_pairs`): it finds the joint moves one-at-a-time
service cannot (an AV on the merging lane keeping its speed while the AV closing from behind brakes). It first takes every AV's
room again under the actions the passes ended with: an AV served early in the second pass was
checked against actions that later AVs of that pass replaced. With ``supervisor_emergency_brake``
(on by default on the merge), an AV that no meta-action leaves room is braked to a stop (a target
speed of 0 m/s, below the speed ladder), and an AV so braked may be released by SLOWER, to the
ladder's lowest speed, which the policy's mask leaves out there (:meth:`Supervisor.choices`).
With ``supervisor_mobil_safety`` (off by default), an AV's lane change is held to the
check MOBIL makes for the HDVs' own: it counts as short of room when the HDV it would cut in front
of, on the target lane or on the lane leading into it, would have to brake harder than its safe
braking (:func:`unsafe_cut_ins`). highway-env's HDVs see no vehicle past the start of the lane they
are about to enter, so an HDV closing at full speed on the main road cannot stop for an AV that
merged just past the ramp's end; the room over the horizon does not show it yet.

A lane an obstacle ends (the merge's merging lane) is a constraint of its own: an AV cannot stop on
it (its lowest target speed is 10 m/s), so an action is also replaced when it leaves the AV on
that lane, at the end of the prediction, with under :data:`~sb3_marl.safety.rooms.LEAVE_TIME` s of driving to the obstacle
(:func:`~sb3_marl.safety.rooms.dead_end_margin`); the replacement is the action with room and a way
off the lane, else with room and the most time left, else the largest room. The prediction runs
as one compiled (numba) function per step; compiled code is cached on disk, so a fresh process
pays the compile time only once.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from sb3_marl.safety.joint_search import keep_lanes_together, search_pairs
from sb3_marl.safety.rooms import (
    AHEAD_ONLY,
    IDLE,
    LANE_LEFT,
    LANE_RIGHT,
    PREFERENCE,
    SLOWER,
    Horizon,
    counted_by,
    dead_end_margin,
    path_room,
    predict,
    set_action,
    set_brake,
    unsafe_cut_ins,
)
from sb3_marl.sim.drivers import lane_distance, lane_order, leader
from sb3_marl.sim.kernel import (
    COLLIDABLE,
    IS_OBSTACLE,
    NO_VEHICLE,
    SPEED,
    TARGET_LANE,
    TARGET_SPEED,
    argsort,
    jit,
)
from sb3_marl.sim.meta_actions import meta_action_targets

#: The supervisor's versions -> (emergency brake, joint search, a braked AV keeps its lane, the
#: prediction a policy step at a time) they turn on: what the config's ``supervisor_version``
#: selects where ``supervisor_emergency_brake`` / ``supervisor_joint_search`` are null. Evaluations
#: record the version, and ``sb3-marl benchmark evaluate`` re-evaluates trials evaluated under
#: another (history in CHANGELOG.md; 3: the road's own equations in the prediction; 4: the
#: emergency brake with its release, :meth:`Supervisor.choices`, and the joint search, the merge's
#: since 2026-12-02; 5: an AV braked below the speed ladder starts no lane change, which at a few m/s
#: would leave it standing across two lanes; 6: version 5 predicting the road a policy step at a
#: time, frames of 1 / policy_frequency s instead of 1 / simulation_frequency s, a third of the
#: work; results/supervisor-v6/).
SUPERVISOR_VERSIONS: dict[int, tuple[bool, bool, bool, bool]] = {
    3: (False, False, False, False),
    4: (True, True, False, False),
    5: (True, True, True, False),
    6: (True, True, True, True),
}
#: The versions the merge accepts (its version 3 released the emergency brake otherwise).
MERGE_SUPERVISOR_VERSIONS = (4, 5, 6)
NO_LEADER_GAP = 1e6  # [m], headway of an AV without leader (priority only)
#: Passes over the AVs in priority order (the second checks against the first pass's final actions).
PASSES = 2


@jit
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
    emergency_brake: bool = False,
    joint_search: bool = False,
    mobil_safety: bool = False,
    brake_keeps_lane: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The supervisor on the road's state array (the kernel's layout, AVs first). Returns the
    executed actions, each AV's room [m] under them (NaN for AVs not served: past the road end) and
    which AVs brake to a stop (IDLE with a target speed of 0 m/s, see ``emergency_brake``).

    :param candidate_lane: (n_avs, 5) target lane of each AV under each meta-action
    :param candidate_speed: (n_avs, 5) target speed [m/s] under each meta-action
    :param available: (n_avs, 5) the action mask
    :param proposed: (n_avs,) the policy's meta-actions
    :param priority: (n_avs,) the order of service, the smallest first (equal: the lower index first)
    :param min_gap: [m] the smallest room an action may leave
    :param rear_avs: whether an AV's room counts the AVs behind it in its lane (see
        :func:`counted_by`)
    :param emergency_brake: when no meta-action leaves an AV ``min_gap`` of room, try braking to a
        stop (target speed 0 m/s, below the speed ladder) and take it if it leaves more room
    :param joint_search: when AVs are still short of room at the end, search their actions in
        pairs with the other AVs' (:func:`~sb3_marl.safety.joint_search.search_pairs`)
    :param mobil_safety: an action of :func:`unsafe_cut_ins` counts as short of room (below
        ``min_gap``), and the joint search leaves such actions out
    :param brake_keeps_lane: an AV braked below the speed ladder (target speed 0 m/s) starts no
        lane change: its lane changes count as short of room, as unsafe cut-ins do
    """
    n_avs = proposed.size
    executed = proposed.copy()
    braking = np.zeros(n_avs, dtype=np.bool_)
    rooms = np.full(n_avs, np.nan)
    state = state0.copy()  # the AVs' targets under the actions being checked
    collidable = state[:, COLLIDABLE] > 0
    dt = horizon.dt
    speed_step = np.zeros(n_avs, dtype=np.int64)
    for i in range(n_avs):
        set_action(state, i, proposed[i], speed_step, candidate_lane, candidate_speed, repeat_actions)
    order = argsort(priority)
    unsafe = np.zeros(candidate_lane.shape, dtype=np.bool_)
    if mobil_safety:
        unsafe = unsafe_cut_ins(state0, n_avs, horizon.lanes, candidate_lane, horizon.speed_limit)
    if brake_keeps_lane:
        for i in range(n_avs):
            if state0[i, TARGET_SPEED] < horizon.ladder[0]:
                for a in (LANE_LEFT, LANE_RIGHT):
                    unsafe[i, a] |= candidate_lane[i, a] != state0[i, TARGET_LANE]
    short = min_gap - 1e-6  # [m] the room an unsafe cut-in (or a braked AV's lane change) counts at most
    # the road predicted under the AVs' current actions, shared by every AV's room until one changes
    path = predict(state, horizon, speed_step, NO_VEHICLE, collidable, -np.inf)[0]
    obstacles = np.flatnonzero(state0[:, IS_OBSTACLE] > 0)
    settled = False  # whether the last pass changed nothing (every room then under the final actions)
    for _ in range(PASSES):
        changed = False
        for i in order:
            if not collidable[i]:
                continue
            counted = counted_by(state0, i, n_avs, collidable, rear_avs)
            current = executed[i]
            room = path_room(i, path, counted, dt)
            if unsafe[i, current] and not braking[i]:
                room = min(room, short)
            dead_end = dead_end_margin(state, i, path, horizon.lanes, obstacles)
            if room < min_gap or dead_end < 0:
                best, best_brake, best_room, best_dead_end, best_path = current, braking[i], room, dead_end, path
                # the meta-actions in tie order, then (as a last resort) the emergency brake
                for k in range(PREFERENCE.size + 1):
                    brake = k == PREFERENCE.size
                    if brake:
                        if not emergency_brake or best_brake or best_room >= min_gap:
                            continue
                        set_brake(state, i, speed_step, candidate_lane)
                        a = IDLE
                    else:
                        a = PREFERENCE[k]
                        if not available[i, a] or (a == current and not braking[i]):
                            continue
                        set_action(state, i, a, speed_step, candidate_lane, candidate_speed, repeat_actions)
                    # stopped once it cannot beat the best room: such a candidate is never
                    # chosen (with a dead end ahead, every candidate is predicted in full)
                    floor = best_room if obstacles.size == 0 else -np.inf
                    # braking counts no AV behind in the lane: they are served after and may brake too
                    seen = counted_by(state0, i, n_avs, collidable, AHEAD_ONLY) if brake else counted
                    candidate_path, candidate_room = predict(state, horizon, speed_step, i, seen, floor)
                    candidate_dead_end = dead_end_margin(state, i, candidate_path, horizon.lanes, obstacles)
                    if unsafe[i, a]:
                        candidate_room = min(candidate_room, short)
                    if _better(candidate_room, candidate_dead_end, best_room, best_dead_end, min_gap):
                        best, best_brake = a, brake
                        best_room, best_dead_end, best_path = candidate_room, candidate_dead_end, candidate_path
                changed = changed or best != current or best_brake != braking[i]
                executed[i], braking[i], room, path = best, best_brake, best_room, best_path
                if best_brake:
                    set_brake(state, i, speed_step, candidate_lane)
                else:
                    set_action(state, i, best, speed_step, candidate_lane, candidate_speed, repeat_actions)
            rooms[i] = room
        if not changed:
            settled = True
            break  # another pass would see the same actions and find the same rooms
    # the joint fallback: AVs short of room after a lane change keep their lanes together
    rooms, state, speed_step = keep_lanes_together(
        state0,
        state,
        speed_step,
        executed,
        rooms,
        order,
        candidate_lane,
        candidate_speed,
        horizon,
        min_gap,
        repeat_actions,
        rear_avs,
    )
    if joint_search:
        executed, braking, rooms = search_pairs(
            state0,
            state,
            speed_step,
            executed,
            braking,
            rooms,
            order,
            candidate_lane,
            candidate_speed,
            available & ~unsafe,
            horizon,
            min_gap,
            repeat_actions,
            rear_avs,
            emergency_brake,
            obstacles,
            settled,
        )
    return executed, rooms, braking


@jit
def _better(room: float, dead_end: float, best_room: float, best_dead_end: float, min_gap: float) -> bool:
    """Whether a candidate action beats the best so far: first the actions with room and a way off
    a dead-end lane (the larger room first), then those with room (the larger dead-end margin
    first), then the larger room."""
    tier = 2 if room >= min_gap and dead_end >= 0 else (1 if room >= min_gap else 0)
    best_tier = 2 if best_room >= min_gap and best_dead_end >= 0 else (1 if best_room >= min_gap else 0)
    if tier != best_tier:
        return tier > best_tier
    return dead_end > best_dead_end if tier == 1 else room > best_room


@jit
def headway_margins(state: np.ndarray, n_avs: int, lanes: np.ndarray, headway_time: float) -> np.ndarray:
    """(n_avs,) each AV's headway margin [m]: the gap to its leader in its lane (:data:`NO_LEADER_GAP`
    without one) minus its speed [m/s] × ``headway_time`` [s] (the lane change's priority)."""
    order = lane_order(state, lanes)
    margin = np.empty(n_avs)
    for i in range(n_avs):
        front = leader(state, lanes, order, i)
        gap = lane_distance(state, lanes, i, front) if front >= 0 else NO_LEADER_GAP
        margin[i] = gap - state[i, SPEED] * headway_time
    return margin


def supervisor_switches(config: dict[str, Any]) -> tuple[bool, bool, bool]:
    """(emergency brake, joint search, a braked AV keeps its lane) of a full scenario config: the
    first two as set, or as its ``supervisor_version`` says where they are null; the third as the
    version says."""
    brake, joint, keep_lane, _ = SUPERVISOR_VERSIONS[config["supervisor_version"]]
    set_brake, set_joint = config["supervisor_emergency_brake"], config["supervisor_joint_search"]
    return (brake if set_brake is None else bool(set_brake), joint if set_joint is None else bool(set_joint), keep_lane)


def prediction_stride(config: dict[str, Any]) -> int:
    """Simulated frames per predicted frame of a full scenario config: 1, or (0) a policy step's
    where its ``supervisor_version`` predicts a policy step at a time."""
    return 0 if SUPERVISOR_VERSIONS[config["supervisor_version"]][3] else 1


@dataclass(frozen=True)
class Supervisor:
    """The supervisor of one scenario config (see the module doc); the env builds it at each reset.

    :param horizon: the road and the prediction's time grid
    :param headway_time: [s] of the priority's headway margin (``headway_time``)
    :param min_gap: [m] the smallest predicted room an action may leave (``supervisor_min_gap``)
    :param repeat_actions: every AV repeats its action at each policy step of the horizon
        (``supervisor_repeat_actions``)
    :param rear_avs: protect each AV from the AVs behind it too (``supervisor_rear_avs``)
    :param emergency_brake: brake to a stop when no meta-action leaves room (``supervisor_emergency_brake``)
    :param joint_search: search the actions of AVs left short of room in pairs (``supervisor_joint_search``)
    :param brake_keeps_lane: an AV braked to a stop starts no lane change (``supervisor_version`` 5)
    :param mobil_safety: hold the AVs' lane changes to MOBIL's safety check (``supervisor_mobil_safety``)
    """

    horizon: Horizon
    headway_time: float
    min_gap: float
    repeat_actions: bool
    rear_avs: bool
    emergency_brake: bool = False
    joint_search: bool = False
    brake_keeps_lane: bool = False
    mobil_safety: bool = False

    @classmethod
    def from_config(
        cls,
        config: dict[str, Any],
        lanes: np.ndarray | None = None,
        road_end: float | None = None,
    ) -> Supervisor:
        """The supervisor of ``config`` on the road ``lanes`` (see :meth:`Horizon.from_config`)."""
        return cls(
            Horizon.from_config(config, lanes, road_end, stride=prediction_stride(config)),
            float(config["headway_time"]),
            float(config["supervisor_min_gap"]),
            bool(config["supervisor_repeat_actions"]),
            bool(config["supervisor_rear_avs"]),
            *supervisor_switches(config),
            bool(config["supervisor_mobil_safety"]),
        )

    def choices(self, state: np.ndarray, n_avs: int, available: np.ndarray) -> np.ndarray:
        """(n_avs, 5) the meta-actions the supervisor may execute: the policy's mask ``available``
        and, with the emergency brake, SLOWER for an AV braked below the speed ladder (the brake's
        release: highway-env's SLOWER at the ladder's bottom step sets its lowest speed, but its mask
        leaves SLOWER out there, so the AV could otherwise only keep braking or take FASTER to the
        ladder's second speed)."""
        choices = np.array(available, dtype=np.bool_)
        if self.emergency_brake:
            choices[:, SLOWER] |= state[:n_avs, TARGET_SPEED] < self.horizon.ladder[0]
        return choices

    def __call__(
        self, state: np.ndarray, n_avs: int, proposed: np.ndarray, available: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Executed meta-actions (n_avs,), each AV's predicted room [m] and which AVs brake to a stop.

        :param state: the road's state array (:mod:`~sb3_marl.sim.kernel` layout), the ``n_avs`` AVs
            first; not modified
        :param proposed: (n_avs,) the policy's meta-actions
        :param available: (n_avs, 5) bool action mask
        """
        horizon = self.horizon
        candidate_lane, candidate_speed = meta_action_targets(state, n_avs, horizon.lanes, horizon.ladder)
        priority = headway_margins(state, n_avs, horizon.lanes, self.headway_time)
        return supervise_arrays(
            state,
            candidate_lane,
            candidate_speed,
            self.choices(state, n_avs, available),
            np.asarray(proposed, dtype=np.int64),
            priority,
            horizon,
            self.min_gap,
            self.repeat_actions,
            self.rear_avs,
            self.emergency_brake,
            self.joint_search,
            self.mobil_safety,
            self.brake_keeps_lane,
        )
