"""The AVs' meta-actions on the state array, compiled: which are available (highway-env's
``DiscreteMetaAction`` rules), the lane and target speed each sets (``MDPVehicle.act``), and the
speed ladder, on the road's lane table (:mod:`sb3_marl.sim.lanes`). Units: m, m/s."""

from __future__ import annotations

from typing import Any

import numpy as np
from highway_env.envs.common.action import DiscreteMetaAction

from sb3_marl.sim.kernel import LANE, SPEED, TARGET_LANE, TARGET_SPEED, X, Y, jit
from sb3_marl.sim.lanes import LEFT, RIGHT, follow, reachable_from

#: Meta-action index -> label, highway-env's ``DiscreteMetaAction`` numbering.
ACTIONS: dict[int, str] = dict(DiscreteMetaAction.ACTIONS_ALL)
ACTION_INDEX: dict[str, int] = {label: index for index, label in ACTIONS.items()}


def check_actions(action: Any, n_avs: int) -> np.ndarray:
    """``action`` as an int array (n_avs,) of meta-action indices, or a ValueError saying what is wrong."""
    actions = np.asarray(action)
    if actions.shape == () and n_avs == 1:
        actions = actions.reshape(1)
    if actions.shape != (n_avs,) or not np.issubdtype(actions.dtype, np.integer):
        raise ValueError(
            f"Invalid action {action!r}: expected an int array of shape ({n_avs},), "
            f"one meta-action per AV, got dtype {actions.dtype} and shape {actions.shape}."
        )
    if not all(0 <= a < len(ACTIONS) for a in actions.tolist()):
        raise ValueError(f"Invalid action {actions.tolist()}: each must be in {ACTIONS}.")
    return actions


@jit
def speed_index(speed: float, ladder: np.ndarray) -> int:
    """``MDPVehicle.speed_to_index``: the index of the target speed nearest ``speed`` [m/s] on the
    uniform ``ladder`` [m/s] (rounding half to even, as ``np.round``)."""
    top = ladder.size - 1
    return int(min(max(np.round((speed - ladder[0]) / (ladder[top] - ladder[0]) * top), 0), top))


@jit
def available_actions(state: np.ndarray, n_avs: int, lanes: np.ndarray, ladder: np.ndarray) -> np.ndarray:
    """(n_avs, 5) bool: highway-env's ``DiscreteMetaAction.get_available_actions`` for each AV (the
    first ``n_avs`` rows) on the road ``lanes`` (:mod:`~sb3_marl.sim.lanes`): IDLE always, a lane
    change towards a side lane of its current lane that is reachable from the AV's position,
    FASTER / SLOWER unless its target speed is already the top / bottom of the ``ladder`` [m/s]."""
    mask = np.zeros((n_avs, 5), dtype=np.bool_)
    top = ladder.size - 1
    for i in range(n_avs):
        lane, x, y = int(state[i, LANE]), state[i, X], state[i, Y]
        mask[i, 0] = reachable_from(lanes, int(lanes[lane, LEFT]), x, y)
        mask[i, 1] = True
        mask[i, 2] = reachable_from(lanes, int(lanes[lane, RIGHT]), x, y)
        index = speed_index(state[i, TARGET_SPEED], ladder)
        mask[i, 3], mask[i, 4] = index < top, index > 0
    return mask


@jit
def meta_action_targets(state: np.ndarray, n_avs: int, lanes: np.ndarray, ladder: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(n_avs, 5) target lane and (n_avs, 5) target speed [m/s] of each AV (the first ``n_avs``
    rows) under each meta-action, as highway-env's ``MDPVehicle.act`` sets them (LANE_LEFT 0,
    IDLE 1, LANE_RIGHT 2, FASTER 3, SLOWER 4): the target lane first follows the road past its
    end (:func:`~sb3_marl.sim.lanes.follow`), a lane change then moves it to its side lane if
    that is reachable, a speed change moves one step up or down the ``ladder`` [m/s] from the step
    nearest the AV's speed; past the ladder's or the road's edge nothing changes."""
    top = ladder.size - 1
    target_lane, target_speed = np.empty((n_avs, 5)), np.empty((n_avs, 5))
    for i in range(n_avs):
        x, y = state[i, X], state[i, Y]
        lane = follow(lanes, int(state[i, TARGET_LANE]), x, y)
        target_lane[i, :] = lane
        for action, column in ((0, LEFT), (2, RIGHT)):
            other = int(lanes[lane, column])
            other = lane if other < 0 else other
            if reachable_from(lanes, other, x, y):
                target_lane[i, action] = other
        target_speed[i, :] = state[i, TARGET_SPEED]
        index = speed_index(state[i, SPEED], ladder)
        target_speed[i, 3] = ladder[min(index + 1, top)]
        target_speed[i, 4] = ladder[max(index - 1, 0)]
    return target_lane, target_speed
