"""The paper's multi-objective reward and the neighbour sets of the local reward.

Per AV i at step t: ``r_i = w_s*r_s + w_d*r_d + w_v*r_v - w_c*r_c`` with

- safety ``r_s = -1`` if the AV crashed, else 0;
- headway ``r_d = min(log(d / (v * t_d)), 0)``: d [m] is the gap (centre to centre) to the
  nearest visible vehicle ahead in the AV's lane, capped at ``headway_max_distance`` (also used
  when there is no leader); v [m/s] the AV's speed, t_d [s] ``headway_time``; 0 when v <= 0;
- speed ``r_v = clip((v - v_min) / (v_max - v_min), 0, 1)`` over ``reward_speed_range``;
- comfort ``r_c = r_a + r_lc``: ``r_a = 1`` when the mean longitudinal acceleration over the
  policy step has ``|a| >= harsh_acceleration_threshold`` (m/s²), ``r_lc = 1`` when the AV started
  a lane change. Comfort is a penalty (it lowers the reward); ``comfort: false`` drops it.

The default a_th = 3 m/s² is highway-env's IDM comfortable acceleration ``COMFORT_ACC_MAX``:
accelerating or braking harder than a human driver's comfort limit counts as harsh.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sb3_marl.sim.kernel import jit

REWARD_TERMS = ("safety", "headway", "speed", "comfort", "harsh_acceleration", "lane_change")


def reward_terms(raw: np.ndarray) -> dict[str, np.ndarray]:
    """Unweighted reward terms per AV by name (:data:`REWARD_TERMS`: ``safety``, ``headway``,
    ``speed``, ``comfort`` = ``harsh_acceleration`` + ``lane_change``), then the
    ``headway_distance`` used [m], from :func:`_terms`' rows (``raw``, (7, n_avs), its headway row
    turned into the term in place)."""
    raw[1] = np.minimum(np.log(raw[1]), 0.0)  # numpy's log: the same on every CPU, as the committed results
    return dict(zip((*REWARD_TERMS, "headway_distance"), raw))


@jit
def _terms(
    x: np.ndarray,
    lane: np.ndarray,
    visible: np.ndarray,
    speed: np.ndarray,
    n_avs: int,
    crashed: np.ndarray,
    acceleration: np.ndarray,
    lane_change: np.ndarray,
    max_distance: float,
    headway_time: float,
    v_min: float,
    v_max: float,
    harsh_threshold: float,
) -> np.ndarray:
    """(7, n_avs): the terms of AVs ``0..n_avs-1`` (``crashed``, ``acceleration`` [m/s²] over the
    policy step, ``lane_change`` started, per AV) among the road's vehicles (``x`` [m], ``lane``,
    ``visible``, ``speed`` [m/s], AVs first) in :data:`REWARD_TERMS` order, then the headway
    distance [m]; the headway row holds d / (v t_d) (1 when v <= 0), whose log :func:`reward_terms`
    takes."""
    terms = np.empty((7, n_avs))
    for i in range(n_avs):
        distance = max_distance  # to the nearest visible vehicle ahead in the lane, capped
        for j in range(x.size):
            if j != i and visible[j] and lane[j] == lane[i] and x[j] > x[i]:
                distance = min(distance, x[j] - x[i])
        harsh = 1.0 if abs(acceleration[i]) >= harsh_threshold else 0.0
        changed = 1.0 if lane_change[i] else 0.0
        terms[0, i] = -1.0 if crashed[i] else -0.0
        terms[1, i] = distance / (max(speed[i], 1e-9) * headway_time) if speed[i] > 0 else 1.0
        terms[2, i] = min(max((speed[i] - v_min) / (v_max - v_min), 0.0), 1.0)
        terms[3, i] = harsh + changed
        terms[4, i] = harsh
        terms[5, i] = changed
        terms[6, i] = distance
    return terms


def total_reward(terms: dict[str, np.ndarray], config: dict[str, Any]) -> np.ndarray:
    """(n_avs,) weighted reward ``w_s*r_s + w_d*r_d + w_v*r_v - w_c*r_c`` (comfort only if enabled)."""
    return _weighted(
        terms["safety"],
        terms["headway"],
        terms["speed"],
        terms["comfort"],
        float(config["safety_weight"]),
        float(config["headway_weight"]),
        float(config["speed_weight"]),
        float(config["comfort_weight"]) if config["comfort"] else 0.0,
    )


@jit
def _weighted(
    safety: np.ndarray,
    headway: np.ndarray,
    speed: np.ndarray,
    comfort: np.ndarray,
    w_s: float,
    w_d: float,
    w_v: float,
    w_c: float,
) -> np.ndarray:
    reward = np.empty(safety.size)
    for i in range(safety.size):
        reward[i] = w_s * safety[i] + w_d * headway[i] + w_v * speed[i]
        if w_c:
            reward[i] -= w_c * comfort[i]
    return reward


@jit
def _neighbour_matrix(x: np.ndarray, lane: np.ndarray, visible: np.ndarray, n: int) -> np.ndarray:
    """(n, n) bool: row i is the neighbour set of AV i (the road's vehicles ``x`` [m], ``lane``,
    ``visible``, the n AVs first) used by the local reward. The set holds AV i itself and, in AV
    i's lane and each adjacent lane, the nearest visible AV ahead (dx >= 0) and the nearest visible
    AV behind (dx < 0); among equally near AVs the first one. AVs past the road end are in no other
    AV's set, and their own set is themselves only."""
    neighbours = np.eye(n, dtype=np.bool_)
    nearest = np.empty((3, 2), dtype=np.int64)  # (lane offset + 1, ahead) -> AV, -1: none
    for i in range(n):
        if not visible[i]:
            continue
        nearest[:] = -1
        for j in range(n):
            if j == i or not visible[j] or abs(lane[j] - lane[i]) > 1:
                continue
            dx = x[j] - x[i]
            side, ahead = lane[j] - lane[i] + 1, int(dx >= 0)
            k = nearest[side, ahead]
            if k < 0 or abs(dx) < abs(x[k] - x[i]):
                nearest[side, ahead] = j
        for side in range(3):
            for ahead in range(2):
                if nearest[side, ahead] >= 0:
                    neighbours[i, nearest[side, ahead]] = True
    return neighbours


#: How an AV's training reward is formed from the per-AV rewards of its scenario copy.
REWARD_MODES = ("local", "global", "individual")


def apply_reward_mode(info: dict[str, Any], reward_mode: str) -> np.ndarray:
    """(n_avs,) rewards of one copy's AVs in a reward mode, from the copy's step info: ``local``
    (the paper's) is the mean of the per-AV rewards over the AV's neighbour set
    (:func:`_neighbour_matrix`), ``global`` the mean over all AVs, ``individual`` the AV's own."""
    own = np.asarray(info["rewards"], dtype=np.float64)
    neighbours = np.asarray(info["neighbours"], dtype=np.bool_)
    return mode_rewards(own, neighbours, REWARD_MODES.index(reward_mode))


@jit
def mode_rewards(own: np.ndarray, neighbours: np.ndarray, mode: int) -> np.ndarray:
    """:func:`apply_reward_mode` on arrays: ``own`` (n,) rewards, ``neighbours`` (n, n) bool sets,
    ``mode`` an index of :data:`REWARD_MODES`."""
    n = own.size
    if mode == 2:
        return own.copy()
    rewards = np.empty(n)
    if mode == 1:
        total = 0.0
        for j in range(n):
            total += own[j]
        rewards[:] = total / n
        return rewards
    for i in range(n):
        total, count = 0.0, 0
        for j in range(n):
            if neighbours[i, j]:
                total += own[j]
                count += 1
        rewards[i] = total / count
    return rewards
