"""Road and traffic of the lane-change scenario: a straight one-way highway and a random spawn.

Positions are in m, speeds in m/s. The highway runs along +x from x = 0 to ``road_length``;
lane 0 is at y = 0 and lane k at y = k * lane_width.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from highway_env.road.lane import LineType, StraightLane
from highway_env.road.road import Road, RoadNetwork
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.controller import MDPVehicle


class PrefilteredCollisionRoad(Road):
    """highway-env's ``Road`` with the pairwise collision tests pre-filtered for all pairs at once.

    ``Road.step`` calls ``handle_collisions(vehicles[i], vehicles[j])`` on every pair i < j. That
    routine does nothing unless (1) the centres are within the "spherical" reach
    ``(diag_i + diag_j) / 2 + speed_i * dt`` and (2) highway-env's separating-axis test finds the
    rectangles intersecting now or after the displacement ``velocity * dt``. Here both are bounded
    for all pairs in numpy: (1) exactly, and (2) on the two axes of vehicle i's rectangle, which the
    separating-axis test also checks; a pair is skipped only when it is separated on one of them by
    more than ``SLACK`` m even after the whole relative displacement. The other pairs reach
    highway-env's exact routine in the stock order, so trajectories are identical to ``Road``'s
    (tests/envs/test_road.py checks it on crash-heavy random episodes).
    """

    SLACK = 1e-6  # [m], far above the rounding error of positions of a few hundred m

    def step(self, dt: float) -> None:
        """Step every vehicle's dynamics by ``dt`` s, then resolve collisions."""
        vehicles = self.vehicles
        for vehicle in vehicles:
            vehicle.step(dt)
        if len(vehicles) > 1:
            for i, j in self._candidate_pairs(dt):
                vehicles[i].handle_collisions(vehicles[j], dt)
        for vehicle in vehicles:
            for other in self.objects:
                vehicle.handle_collisions(other, dt)

    def _candidate_pairs(self, dt: float) -> np.ndarray:
        """(k, 2) pairs i < j, row-major, that may collide within ``dt`` s."""
        state = np.array(
            [(*v.position, v.heading, v.speed, v.diagonal, v.LENGTH, v.WIDTH) for v in self.vehicles]
        )
        x, y, heading, speed, diagonal, length, width = state.T
        centre_gap = np.stack([x[None, :] - x[:, None], y[None, :] - y[:, None]])  # [., i, j]: j - i
        velocity = speed * np.stack([np.cos(heading), np.sin(heading)])
        relative_motion = (velocity[:, :, None] - velocity[:, None, :]) * dt  # [., i, j]: i - j
        maybe = np.hypot(*centre_gap) <= (diagonal[:, None] + diagonal[None, :]) / 2 + speed[:, None] * dt
        cos_d = np.abs(np.cos(heading[None, :] - heading[:, None]))
        sin_d = np.abs(np.sin(heading[None, :] - heading[:, None]))
        half_l, half_w = length / 2, width / 2
        for axis, own_half, other_half in (
            (np.stack([np.cos(heading), np.sin(heading)]), half_l, half_l[None, :] * cos_d + half_w[None, :] * sin_d),
            (np.stack([-np.sin(heading), np.cos(heading)]), half_w, half_l[None, :] * sin_d + half_w[None, :] * cos_d),
        ):
            separation = (
                np.abs(np.einsum("ci,cij->ij", axis, centre_gap))
                - own_half[:, None]
                - other_half
                - np.abs(np.einsum("ci,cij->ij", axis, relative_motion))
            )
            maybe &= separation <= self.SLACK
        return np.argwhere(np.triu(maybe, k=1))


def make_road(
    config: dict[str, Any], np_random: np.random.Generator, road_class: type[Road] = PrefilteredCollisionRoad
) -> Road:
    """A one-way highway of ``lanes_count`` straight lanes of ``road_length`` m.

    :param config: the scenario config
    :param np_random: the env's random generator, shared with the vehicles' behaviour
    :param road_class: highway-env's ``Road`` or a faster equivalent
    """
    network = RoadNetwork()
    lanes = config["lanes_count"]
    width = config["lane_width"]
    for lane in range(lanes):
        y = lane * width
        line_types = (
            LineType.CONTINUOUS_LINE if lane == 0 else LineType.STRIPED,
            LineType.CONTINUOUS_LINE if lane == lanes - 1 else LineType.NONE,
        )
        network.add_lane(
            "start",
            "end",
            StraightLane(
                [0.0, y],
                [config["road_length"], y],
                width=width,
                line_types=line_types,
                speed_limit=config["speed_limit"],
            ),
        )
    return road_class(network=network, np_random=np_random, record_history=config["show_trajectories"])


def configure_hdv(vehicle: IDMVehicle, config: dict[str, Any]) -> None:
    """Apply the config's MOBIL parameters to one HDV instance (IDM keeps highway-env's defaults).

    :param vehicle: a human-driven vehicle
    :param config: the scenario config (``hdv_politeness``, ``hdv_b_safe`` in m/s²,
        ``hdv_lane_change_threshold`` in m/s²)
    """
    vehicle.POLITENESS = float(config["hdv_politeness"])
    vehicle.LANE_CHANGE_MAX_BRAKING_IMPOSED = float(config["hdv_b_safe"])
    vehicle.LANE_CHANGE_MIN_ACC_GAIN = float(config["hdv_lane_change_threshold"])


def spawn_vehicles(
    road: Road,
    config: dict[str, Any],
    n_avs: int,
    n_hdvs: int,
    np_random: np.random.Generator,
) -> tuple[list[MDPVehicle], list[IDMVehicle]]:
    """Place AVs and HDVs in distinct random slots of a grid along every lane.

    Slots are ``spawn_spacing`` m apart from ``spawn_start`` on each lane, jittered by up to
    ``spawn_position_noise`` m, so vehicles never overlap (validation guarantees the spacing
    exceeds the 5 m vehicle length plus twice the noise). Initial speeds are uniform in
    ``spawn_speed_range`` (m/s). AVs come first in ``road.vehicles``.

    :return: the AVs (highway-env ``MDPVehicle``) and the HDVs (``IDMVehicle`` with MOBIL)
    """
    lanes = road.network.lanes_list()
    per_lane = config["spawn_slots_per_lane"]
    slots = np_random.choice(len(lanes) * per_lane, size=n_avs + n_hdvs, replace=False)
    noise = np_random.uniform(-1.0, 1.0, size=slots.size) * config["spawn_position_noise"]
    speeds = np_random.uniform(*config["spawn_speed_range"], size=slots.size)

    avs: list[MDPVehicle] = []
    hdvs: list[IDMVehicle] = []
    for i, (slot, dx, speed) in enumerate(zip(slots, noise, speeds)):
        lane = lanes[slot // per_lane]
        x = config["spawn_start"] + (slot % per_lane) * config["spawn_spacing"] + dx
        position, heading = lane.position(x, 0.0), lane.heading_at(x)
        if i < n_avs:
            av = MDPVehicle(road, position, heading, float(speed), target_speeds=config["target_speeds"])
            avs.append(av)
        else:
            hdv = IDMVehicle(road, position, heading, float(speed))
            configure_hdv(hdv, config)
            hdvs.append(hdv)
    road.vehicles.extend(avs)
    road.vehicles.extend(hdvs)
    return avs, hdvs
