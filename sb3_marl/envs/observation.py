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

from sb3_marl.envs.traffic import TrafficSnapshot

FEATURES = ("presence", "x", "y", "vx", "vy")


def observation_space(n_avs: int, config: dict[str, Any]) -> spaces.Box:
    """Box of shape (n_avs, obs_vehicles_count, 5) in [-1, 1]."""
    shape = (n_avs, config["obs_vehicles_count"], len(FEATURES))
    return spaces.Box(low=-1.0, high=1.0, shape=shape, dtype=np.float32)


def observe(snapshot: TrafficSnapshot, config: dict[str, Any]) -> np.ndarray:
    """Observations of all AVs, shape (n_avs, obs_vehicles_count, 5), float32."""
    n_avs, rows = snapshot.n_avs, config["obs_vehicles_count"]
    scale = np.array([config["obs_x_range"], config["obs_y_range"], config["obs_speed_range"],
                      config["obs_speed_range"]])
    obs = np.zeros((n_avs, rows, len(FEATURES)), dtype=np.float32)
    state = np.stack([snapshot.x, snapshot.y, snapshot.vx, snapshot.vy], axis=1)  # (n, 4)

    ego = state[:n_avs]
    obs[:, 0, 0] = 1.0
    obs[:, 0, 1] = np.clip(ego[:, 0] / config["road_length"], 0.0, 1.0)
    obs[:, 0, 2:] = np.clip(ego[:, 1:] / scale[1:], -1.0, 1.0)

    if rows > 1:
        dx = snapshot.others_dx()
        distance = np.where(
            snapshot.seen_by_avs() & (np.abs(dx) <= config["obs_x_range"]), np.abs(dx), np.inf
        )
        nearest = np.argsort(distance, axis=1, kind="stable")[:, : rows - 1]  # (n_avs, k)
        present = np.isfinite(np.take_along_axis(distance, nearest, axis=1))
        relative = (state[nearest] - ego[:, None, :]) / scale  # (n_avs, k, 4)
        k = nearest.shape[1]
        obs[:, 1 : 1 + k, 0] = present
        obs[:, 1 : 1 + k, 1:] = np.where(present[..., None], np.clip(relative, -1.0, 1.0), 0.0)
    return obs
