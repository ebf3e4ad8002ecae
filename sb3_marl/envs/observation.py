"""Kinematic observation of the AVs, computed with numpy for all AVs at once.

Per AV, a matrix of ``obs_vehicles_count`` rows x 5 features ``(presence, x, y, vx, vy)``:

- row 0 is the ego AV in absolute terms: x / road_length (clipped to [0, 1]: progress along
  the road), y / obs_y_range, vx / obs_speed_range, vy / obs_speed_range;
- rows 1.. are the nearest other visible vehicles (AV or HDV, nearest |dx| first, within
  ``obs_x_range`` m), relative to the ego: dx / obs_x_range, dy / obs_y_range,
  dvx / obs_speed_range, dvy / obs_speed_range, clipped to [-1, 1];
- absent rows are all zeros (presence 0).

Vehicles past the road end never appear. This matches highway-env's ``Kinematics`` observation
(``absolute=False``, normalised, ego row first) without its per-step pandas cost.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces

from sb3_marl.envs.simulator import clip
from sb3_marl.envs.traffic import TrafficSnapshot

FEATURES = ("presence", "x", "y", "vx", "vy")


def observation_space(n_avs: int, config: dict[str, Any]) -> spaces.Box:
    """Box of shape (n_avs, obs_vehicles_count, 5) in [-1, 1]."""
    shape = (n_avs, config["obs_vehicles_count"], len(FEATURES))
    return spaces.Box(low=-1.0, high=1.0, shape=shape, dtype=np.float32)


def observe(snapshot: TrafficSnapshot, config: dict[str, Any]) -> np.ndarray:
    """Observations of all AVs, shape (n_avs, obs_vehicles_count, 5), float32.

    Plain Python over the (at most a dozen) vehicles: on arrays this small, each numpy call costs
    more than the whole loop.
    """
    n_avs, rows = snapshot.n_avs, config["obs_vehicles_count"]
    x_range, y_range, v_range = config["obs_x_range"], config["obs_y_range"], config["obs_speed_range"]
    road_length = config["road_length"]
    x, y, vx, vy = snapshot.x.tolist(), snapshot.y.tolist(), snapshot.vx.tolist(), snapshot.vy.tolist()
    others = snapshot.visible_others
    obs = np.zeros((n_avs, rows, len(FEATURES)), dtype=np.float32)
    for i in range(n_avs):
        matrix = [[1.0, clip(x[i] / road_length, 0.0, 1.0), clip(y[i] / y_range), clip(vx[i] / v_range),
                   clip(vy[i] / v_range)]]
        nearest = sorted((abs(x[j] - x[i]), j) for j in others[i] if abs(x[j] - x[i]) <= x_range)
        for _, j in nearest[: rows - 1]:
            matrix.append([1.0, clip((x[j] - x[i]) / x_range), clip((y[j] - y[i]) / y_range),
                           clip((vx[j] - vx[i]) / v_range), clip((vy[j] - vy[i]) / v_range)])
        obs[i, : len(matrix)] = matrix
    return obs
