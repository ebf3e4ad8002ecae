"""A numpy snapshot of the traffic after each policy step, shared by observation and reward."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from highway_env.vehicle.kinematics import Vehicle


@dataclass(frozen=True)
class TrafficSnapshot:
    """State of every vehicle on the road; AVs are the first ``n_avs`` entries.

    :param x: longitudinal position [m]
    :param y: lateral position [m]
    :param vx: longitudinal velocity [m/s]
    :param vy: lateral velocity [m/s]
    :param speed: speed along the heading [m/s]
    :param lane: index of the lane the vehicle is on (0 = y 0)
    :param visible: False for vehicles past the road end, which are ignored
    :param n_avs: number of AVs (the first entries)
    """

    x: np.ndarray
    y: np.ndarray
    vx: np.ndarray
    vy: np.ndarray
    speed: np.ndarray
    lane: np.ndarray
    visible: np.ndarray
    n_avs: int

    @classmethod
    def capture(cls, vehicles: list[Vehicle], n_avs: int, road_length: float) -> TrafficSnapshot:
        """Read positions and velocities of ``vehicles`` (AVs first) into arrays.

        :param road_length: [m] vehicles whose centre is past it are not visible
        """
        state = np.array(
            [
                (v.position[0], v.position[1], v.speed * np.cos(v.heading), v.speed * np.sin(v.heading),
                 v.speed, v.lane_index[2])
                for v in vehicles
            ],
            dtype=np.float64,
        ).reshape(-1, 6)
        x = state[:, 0]
        return cls(
            x=x,
            y=state[:, 1],
            vx=state[:, 2],
            vy=state[:, 3],
            speed=state[:, 4],
            lane=state[:, 5].astype(np.int64),
            visible=x <= road_length,
            n_avs=n_avs,
        )

    def others_dx(self) -> np.ndarray:
        """(n_avs, n_vehicles) longitudinal offsets x_j - x_i [m] of every vehicle j seen from AV i."""
        return self.x[None, :] - self.x[: self.n_avs, None]

    def seen_by_avs(self) -> np.ndarray:
        """(n_avs, n_vehicles) mask: vehicle j is another, visible vehicle for AV i."""
        seen = np.broadcast_to(self.visible, (self.n_avs, self.x.size)).copy()
        seen[np.arange(self.n_avs), np.arange(self.n_avs)] = False
        return seen
