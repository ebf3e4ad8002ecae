"""The supervisor's joint search (``supervisor_joint_search``): the AVs left short of room after
the passes have their options searched in pairs with every other AV's, the whole road predicted
for each pair (:func:`search_pairs`). Units: m, s."""

from __future__ import annotations

import numpy as np

from sb3_marl.safety.rooms import (
    IDLE,
    LANE_LEFT,
    LANE_RIGHT,
    PREFERENCE,
    Horizon,
    av_rooms,
    counted_by_all,
    dead_end_margin,
    predict,
    set_action,
    set_brake,
)
from sb3_marl.sim.kernel import COLLIDABLE, NO_VEHICLE, jit

#: The emergency brake as an option of the joint search (after the five meta-actions).
BRAKE = 5


@jit
def keep_lanes_together(
    state0: np.ndarray,
    state: np.ndarray,
    speed_step: np.ndarray,
    executed: np.ndarray,
    rooms: np.ndarray,
    order: np.ndarray,
    candidate_lane: np.ndarray,
    candidate_speed: np.ndarray,
    horizon: Horizon,
    min_gap: float,
    repeat_actions: bool,
    rear_avs: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The joint fallback after the passes: they serve one AV at a time against the others' current
    actions, so two AVs whose lane changes conflict can each find every option unsafe and end up
    crossing each other. The AVs still short of ``min_gap`` m of room after a lane change keep
    their lanes (IDLE, set in ``executed``) together, if that leaves every served AV more room than
    before. Returns the rooms [m], the predicted state and the speed steps, the trial's where taken."""
    n_avs = executed.size
    collidable = state0[:, COLLIDABLE] > 0
    dt = horizon.dt
    stuck = np.zeros(n_avs, dtype=np.bool_)
    for i in order:
        stuck[i] = collidable[i] and rooms[i] < min_gap and (executed[i] == LANE_LEFT or executed[i] == LANE_RIGHT)
    if stuck.any():
        trial, trial_step = state.copy(), speed_step.copy()
        for i in range(n_avs):
            if stuck[i]:
                set_action(trial, i, IDLE, trial_step, candidate_lane, candidate_speed, repeat_actions)
        trial_path = predict(trial, horizon, trial_step, NO_VEHICLE, collidable, -np.inf)[0]
        trial_rooms = av_rooms(trial_path, counted_by_all(state0, n_avs, collidable, rear_avs), collidable, dt)
        before, after = np.inf, np.inf
        for i in range(n_avs):
            if collidable[i]:
                before, after = min(before, rooms[i]), min(after, trial_rooms[i])
        if after > before:
            for i in range(n_avs):
                if stuck[i]:
                    executed[i] = IDLE
            rooms, state, speed_step = trial_rooms, trial, trial_step
    return rooms, state, speed_step


@jit
def _set_option(
    state: np.ndarray,
    i: int,
    option: int,
    speed_step: np.ndarray,
    candidate_lane: np.ndarray,
    candidate_speed: np.ndarray,
    repeat_actions: bool,
) -> None:
    """Option ``option`` of AV ``i``: a meta-action index, or ``BRAKE`` (the emergency brake)."""
    if option == BRAKE:
        set_brake(state, i, speed_step, candidate_lane)
    else:
        set_action(state, i, option, speed_step, candidate_lane, candidate_speed, repeat_actions)


@jit
def _joint_score(
    state: np.ndarray,
    speed_step: np.ndarray,
    horizon: Horizon,
    counted: np.ndarray,
    collidable: np.ndarray,
    obstacles: np.ndarray,
    min_gap: float,
    n_avs: int,
) -> tuple[float, float, float, np.ndarray]:
    """(worst room shortfall, worst dead-end shortfall, summed room shortfall) [m] of the AVs' set
    actions (each 0 when every AV has room / a way off), and the AVs' rooms [m]."""
    path = predict(state, horizon, speed_step, NO_VEHICLE, collidable, -np.inf)[0]
    rooms = av_rooms(path, counted, collidable, horizon.dt)
    worst, dead, total = 0.0, 0.0, 0.0
    for i in range(n_avs):
        if collidable[i]:
            short = min(rooms[i] - min_gap, 0.0)
            worst, total = min(worst, short), total + short
            dead = min(dead, dead_end_margin(state, i, path, horizon.lanes, obstacles), 0.0)
    return worst, dead, total, rooms


@jit
def search_pairs(
    state0: np.ndarray,
    state: np.ndarray,
    speed_step: np.ndarray,
    executed: np.ndarray,
    braking: np.ndarray,
    rooms: np.ndarray,
    order: np.ndarray,
    candidate_lane: np.ndarray,
    candidate_speed: np.ndarray,
    available: np.ndarray,
    horizon: Horizon,
    min_gap: float,
    repeat_actions: bool,
    rear_avs: bool,
    emergency_brake: bool,
    obstacles: np.ndarray,
    settled: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Joint search (``supervisor_joint_search``): while AVs are left short of ``min_gap`` m of room
    after the passes (every room taken again under the final actions unless the last pass was
    ``settled``: changed nothing), try each such AV's options (its available meta-actions and, with
    ``emergency_brake``, the brake) together with each other AV's, the whole road predicted for
    every pair, and keep the pair that leaves the worst-off AV the most room (then the most time to
    leave a dead end, then the least summed shortfall); repeated while it improves, at most once
    per AV. Returns the executed actions, which AVs brake, and the AVs' rooms [m]."""
    n_avs = executed.size
    collidable = state0[:, COLLIDABLE] > 0
    if settled and not (collidable[:n_avs] & (rooms < min_gap)).any():
        return executed, braking, rooms  # nobody short: no prediction needed
    counted = counted_by_all(state0, n_avs, collidable, rear_avs)
    options = np.zeros((n_avs, PREFERENCE.size + 1), dtype=np.bool_)
    for i in range(n_avs):
        for a in range(PREFERENCE.size):
            options[i, a] = available[i, a]
        options[i, BRAKE] = emergency_brake
    option = executed.copy()
    for i in range(n_avs):
        if braking[i]:
            option[i] = BRAKE
    best = _joint_score(state, speed_step, horizon, counted, collidable, obstacles, min_gap, n_avs)
    rooms = best[3]  # under the final actions (an AV served early in the last pass was checked against others')
    for _ in range(n_avs):
        if best[0] >= 0.0 and best[1] >= 0.0:
            break
        improved = False
        for i in order:
            if not collidable[i] or rooms[i] >= min_gap:
                continue
            best_pair = (NO_VEHICLE, NO_VEHICLE, NO_VEHICLE, NO_VEHICLE)
            for j in order:
                if not collidable[j]:
                    continue
                for a in range(PREFERENCE.size + 1):
                    if not options[i, a]:
                        continue
                    for b in range(PREFERENCE.size + 1):
                        if not options[j, b] or (j == i and b != a):
                            continue
                        if a == option[i] and b == option[j]:
                            continue
                        trial, trial_step = state.copy(), speed_step.copy()
                        _set_option(trial, i, a, trial_step, candidate_lane, candidate_speed, repeat_actions)
                        _set_option(trial, j, b, trial_step, candidate_lane, candidate_speed, repeat_actions)
                        score = _joint_score(trial, trial_step, horizon, counted, collidable, obstacles, min_gap, n_avs)
                        if (score[0], score[1], score[2]) > (best[0], best[1], best[2]):
                            best, best_pair = score, (i, a, j, b)
            if best_pair[0] >= 0:
                i_, a, j, b = best_pair
                _set_option(state, i_, a, speed_step, candidate_lane, candidate_speed, repeat_actions)
                _set_option(state, j, b, speed_step, candidate_lane, candidate_speed, repeat_actions)
                option[i_], option[j] = a, b
                rooms = best[3]
                improved = True
        if not improved:
            break
    for i in range(n_avs):
        braking[i] = option[i] == BRAKE
        executed[i] = IDLE if braking[i] else option[i]
    return executed, braking, rooms
