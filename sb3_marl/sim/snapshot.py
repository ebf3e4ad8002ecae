"""A numpy snapshot of the traffic after each policy step, shared by observation and reward."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sb3_marl.sim import kernel


@dataclass(frozen=True)
class TrafficSnapshot:
    """State of every vehicle on the road; AVs are the first ``n_avs`` entries.

    :param x: longitudinal position [m]
    :param y: lateral position [m]
    :param vx: longitudinal velocity [m/s]
    :param vy: lateral velocity [m/s]
    :param speed: speed along the heading [m/s]
    :param lane: index of the lane the vehicle is on (0 = y 0)
    :param visible: False for vehicles past the road end, which are ignored, and for obstacles
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
    def capture(cls, state: np.ndarray, n_avs: int, road_end: float) -> TrafficSnapshot:
        """The snapshot of the road's state array (:mod:`~sb3_marl.sim.kernel` layout, AVs first).

        :param road_end: [m] vehicles whose centre is past it are not visible
        """
        x, speed, heading = state[:, kernel.X], state[:, kernel.SPEED], state[:, kernel.HEADING]
        return cls(
            x=x,
            y=state[:, kernel.Y],
            vx=speed * np.cos(heading),
            vy=speed * np.sin(heading),
            speed=speed,
            lane=state[:, kernel.LANE].astype(np.int64),
            visible=(x <= road_end) & (state[:, kernel.IS_OBSTACLE] == 0),
            n_avs=n_avs,
        )
