"""A numpy snapshot of the traffic after each policy step, shared by observation and reward."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from highway_env.vehicle.kinematics import Vehicle

from sb3_marl.envs.simulator import cos, sin, xy


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
                (*xy(v.position), v.speed * cos(v.heading), v.speed * sin(v.heading), v.speed, v.lane_index[2])
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
