"""One policy step of the whole road, compiled (:func:`policy_step`): the AVs' meta-actions set
their targets, then for each frame every vehicle acts (:func:`sb3_marl.sim.drivers.act`) and moves
(the kinematic bicycle model of ``Vehicle.step`` with the lane update of ``on_state_update``,
:func:`drive`), then the pairwise collision test (:mod:`sb3_marl.sim.collisions`) and the
road-end rule. Units: m, m/s, rad, s."""

from __future__ import annotations

import numpy as np

from sb3_marl.sim.collisions import handle_collisions
from sb3_marl.sim.drivers import act
from sb3_marl.sim.kernel import (
    ACCELERATION,
    COLLIDABLE,
    CRASHED,
    HAS_IMPACT,
    HEADING,
    IMPACT_X,
    IMPACT_Y,
    IS_HDV,
    IS_OBSTACLE,
    LANE,
    LENGTH,
    MAX_SPEED,
    MIN_SPEED,
    PRESENT,
    SPEED,
    STEERING,
    TARGET_LANE,
    TARGET_SPEED,
    TIMER,
    X,
    Y,
    arctan,
    cos,
    jit,
    sin,
    tan,
)
from sb3_marl.sim.lanes import closest_lane
from sb3_marl.sim.meta_actions import meta_action_targets


@jit
def _move(state: np.ndarray, dt: float, lanes: np.ndarray) -> None:
    """``Vehicle.step`` of every vehicle (``IDMVehicle`` also advances its timer); obstacles stay."""
    for k in range(state.shape[0]):
        if not state[k, PRESENT] or state[k, IS_OBSTACLE]:
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
        state[k, LANE] = closest_lane(lanes, state[k, X], state[k, Y], state[k, HEADING])


@jit
def drive(state: np.ndarray, dt: float, lanes: np.ndarray, speed_limit: float) -> None:
    """One frame of the road's driving (``Road.act``, then ``Vehicle.step`` of every vehicle) on
    ``state`` in place, without the collision test and the road end: the safety supervisor's
    prediction, with the same equations as :func:`policy_step`."""
    act(state, lanes, speed_limit)
    _move(state, dt, lanes)


@jit
def policy_step(
    state: np.ndarray,
    actions: np.ndarray,
    frames: int,
    dt: float,
    lanes: np.ndarray,
    road_end: float,
    speed_limit: float,
    ladder: np.ndarray,
    braking: np.ndarray,
) -> np.ndarray:
    """One policy step of the scenario on a copy of ``state``: the first ``actions.size`` rows (the
    AVs) take their meta-actions (:func:`meta_action_targets`; target speed 0 m/s for the AVs
    ``braking``, the safety supervisor's emergency brake), then ``frames`` frames of ``dt`` s
    run (``Road.act``, ``Road.step``); after each, vehicles whose x passes ``road_end`` [m] leave:
    HDVs are removed, AVs stop colliding. Returns the new state without the removed vehicles.

    :param state: (n, :data:`COLUMNS`) one row per vehicle, the AVs first, obstacles last
    :param lanes: the road's lane table (:mod:`sb3_marl.sim.lanes`)
    :param speed_limit: [m/s] the lanes' speed limit (caps IDM's desired speed)
    :param ladder: [m/s] the AVs' target speeds
    """
    state = state.copy()
    n, n_avs = state.shape[0], actions.size
    target_lane, target_speed = meta_action_targets(state, n_avs, lanes, ladder)
    for i in range(n_avs):
        state[i, TARGET_LANE], state[i, TARGET_SPEED] = target_lane[i, actions[i]], target_speed[i, actions[i]]
        if braking[i]:
            state[i, TARGET_SPEED] = 0.0
    for _ in range(frames):
        drive(state, dt, lanes, speed_limit)
        handle_collisions(state, dt)
        for k in range(n):
            if state[k, PRESENT] and state[k, X] > road_end:
                if state[k, IS_HDV]:
                    state[k, PRESENT] = 0.0
                else:
                    state[k, COLLIDABLE] = 0.0
    kept = np.flatnonzero(state[:, PRESENT])
    return state[kept] if kept.size < n else state
