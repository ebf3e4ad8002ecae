"""Kinematic observation of the AVs, computed with numpy for all AVs at once.

Per AV, a matrix of ``obs_vehicles_count`` rows x 5 features ``(presence, x, y, vx, vy)``:

- row 0 is the ego AV in absolute terms: x / road_length (clipped to [0, 1]: progress along
  the road), y / obs_y_range, vx / obs_speed_range, vy / obs_speed_range;
- rows 1.. are the nearest other visible vehicles (AV or HDV, nearest |dx| first, within
  ``obs_x_range`` m), relative to the ego: dx / obs_x_range, dy / obs_y_range,
  dvx / obs_speed_range, dvy / obs_speed_range, clipped to [-1, 1];
- absent rows are all zeros (presence 0);
- with ``obs_target_speed`` (not the paper's), a 6th column: the ego's target speed /
  obs_speed_range on row 0 (the set-point FASTER and SLOWER move, which vx alone does not reveal
  while the speed is still converging to it), 0 on the other rows.

Vehicles past the road end never appear. This matches highway-env's ``Kinematics`` observation
(``absolute=False``, normalised, ego row first) without its per-step pandas cost.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces

from sb3_marl.sim.kernel import argsort, clip, jit

FEATURES = ("presence", "x", "y", "vx", "vy")
TARGET_SPEED_FEATURE = "target_speed"


def features(config: dict[str, Any]) -> tuple[str, ...]:
    """The observed features (columns) under ``config``."""
    return (*FEATURES, TARGET_SPEED_FEATURE) if config["obs_target_speed"] else FEATURES


def observation_space(n_avs: int, config: dict[str, Any]) -> spaces.Box:
    """Box of shape (n_avs, obs_vehicles_count, features) in [-1, 1]."""
    shape = (n_avs, config["obs_vehicles_count"], len(features(config)))
    return spaces.Box(low=-1.0, high=1.0, shape=shape, dtype=np.float32)


@jit
def _observe(
    x: np.ndarray,
    y: np.ndarray,
    vx: np.ndarray,
    vy: np.ndarray,
    visible: np.ndarray,
    n_avs: int,
    rows: int,
    road_length: float,
    x_range: float,
    y_range: float,
    v_range: float,
) -> np.ndarray:
    """(n_avs, rows, 5) float32: the observation of AVs ``0..n_avs-1`` (see the module doc) among
    the road's vehicles (``x``, ``y`` [m], ``vx``, ``vy`` [m/s], ``visible``, AVs first); other
    vehicles are ranked by |dx|, equal distances by index."""
    obs = np.zeros((n_avs, rows, 5), dtype=np.float32)
    distance = np.empty(x.size)
    for i in range(n_avs):
        obs[i, 0] = (
            1.0,
            clip(x[i] / road_length, 0.0, 1.0),
            clip(y[i] / y_range, -1.0, 1.0),
            clip(vx[i] / v_range, -1.0, 1.0),
            clip(vy[i] / v_range, -1.0, 1.0),
        )
        count = 0
        for j in range(x.size):
            distance[j] = abs(x[j] - x[i])
            if j != i and visible[j] and distance[j] <= x_range:
                count += 1
            else:
                distance[j] = np.inf
        order = argsort(distance)  # stable: ties by index
        for row in range(min(count, rows - 1)):
            j = order[row]
            obs[i, row + 1] = (
                1.0,
                clip((x[j] - x[i]) / x_range, -1.0, 1.0),
                clip((y[j] - y[i]) / y_range, -1.0, 1.0),
                clip((vx[j] - vx[i]) / v_range, -1.0, 1.0),
                clip((vy[j] - vy[i]) / v_range, -1.0, 1.0),
            )
    return obs


#: Keys of the centralised-critic observation (a Dict): the AV's own view, which the actor reads,
#: and the copy's global state, which only a centralised critic reads.
LOCAL_KEY, STATE_KEY = "observation", "state"


def centralised_observation_space(agent_space: spaces.Box, max_avs: int) -> spaces.Dict:
    """Per-AV Dict space of :func:`centralised_observations`: ``observation`` (``agent_space``) and
    ``state``, shape (max_avs, 2 + vehicles * features) in [-1, 1]."""
    state_shape = (max_avs, 2 + int(np.prod(agent_space.shape)))
    return spaces.Dict(
        {
            LOCAL_KEY: agent_space,
            STATE_KEY: spaces.Box(low=-1.0, high=1.0, shape=state_shape, dtype=np.float32),
        }
    )


def centralised_observations(copy_obs: np.ndarray, max_avs: int) -> dict[str, np.ndarray]:
    """Every AV's view plus the global state of its scenario copy (the centralised critic's input).

    The state of AV i is one row per AV slot j < ``max_avs`` in a fixed order (the copy's AV
    indices): ``(present_j, j == i, AV j's observation flattened)``; slots past the copy's AV count
    are zero rows (present 0), so copies with fewer AVs than the density's maximum share one shape.

    :param copy_obs: the copy's observations, shape (n_avs, vehicles, features), n_avs <= max_avs
    :return: ``{"observation": copy_obs, "state": (n_avs, max_avs, 2 + vehicles * features)}``
    """
    n_avs = copy_obs.shape[0]
    if n_avs > max_avs:
        raise ValueError(f"A copy of {n_avs} AVs does not fit a centralised state of {max_avs} AV slots.")
    state = np.zeros((n_avs, max_avs, 2 + int(np.prod(copy_obs.shape[1:]))), dtype=np.float32)
    state[:, :n_avs, 0] = 1.0
    state[np.arange(n_avs), np.arange(n_avs), 1] = 1.0
    state[:, :n_avs, 2:] = copy_obs.reshape(n_avs, -1)
    return {LOCAL_KEY: copy_obs, STATE_KEY: state}
