"""Road and traffic of the lane-change scenario: a straight one-way highway and a random spawn.

Positions are in m, speeds in m/s. The highway runs along +x from x = 0 to ``road_length``;
lane 0 is at y = 0 and lane k at y = k * lane_width.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from highway_env.road.lane import LineType
from highway_env.road.road import Road
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.controller import MDPVehicle

from sb3_marl.envs.simulator import COMPILED, Simulator


def make_road(config: dict[str, Any], np_random: np.random.Generator, simulator: Simulator = COMPILED) -> Road:
    """A one-way highway of ``lanes_count`` straight lanes of ``road_length`` m.

    :param config: the scenario config
    :param np_random: the env's random generator, shared with the vehicles' behaviour
    :param simulator: highway-env's classes (:data:`~sb3_marl.envs.simulator.STOCK`) or the faster
        equivalents (:data:`~sb3_marl.envs.simulator.FAST`, :data:`~sb3_marl.envs.simulator.COMPILED`)
    """
    network = simulator.network()
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
            simulator.lane(
                [0.0, y],
                [config["road_length"], y],
                width=width,
                line_types=line_types,
                speed_limit=config["speed_limit"],
            ),
        )
    return simulator.road(network=network, np_random=np_random, record_history=config["show_trajectories"])


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
    simulator: Simulator = COMPILED,
) -> tuple[list[MDPVehicle], list[IDMVehicle]]:
    """Place AVs and HDVs in distinct random slots of a grid along every lane.

    Slots are ``spawn_spacing`` m apart from ``spawn_start`` on each lane, jittered by up to
    ``spawn_position_noise`` m, so vehicles never overlap (validation guarantees the spacing
    exceeds the 5 m vehicle length plus twice the noise). Initial speeds are uniform in
    ``spawn_speed_range`` (m/s). AVs come first in ``road.vehicles``.

    :param simulator: the vehicle classes to spawn (``simulator.av`` and ``simulator.hdv``)
    :return: the AVs (highway-env ``MDPVehicle``) and the HDVs (``IDMVehicle`` with MOBIL)
    """
    lanes = road.network.lanes_list()
    per_lane = config["spawn_slots_per_lane"]
    slots = np_random.choice(len(lanes) * per_lane, size=n_avs + n_hdvs, replace=False)
    noise = np_random.uniform(-1.0, 1.0, size=slots.size) * config["spawn_position_noise"]
    low, high = config["spawn_speed_range"]
    speeds = np_random.uniform(low, high, size=slots.size)

    avs: list[MDPVehicle] = []
    hdvs: list[IDMVehicle] = []
    for i, (slot, dx, speed) in enumerate(zip(slots, noise, speeds)):
        lane = lanes[slot // per_lane]
        x = config["spawn_start"] + (slot % per_lane) * config["spawn_spacing"] + dx
        position, heading = lane.position(x, 0.0), lane.heading_at(x)
        if i < n_avs:
            av = simulator.av(road, position, heading, float(speed), target_speeds=config["target_speeds"])
            avs.append(av)
        else:
            hdv = simulator.hdv(road, position, heading, float(speed))
            configure_hdv(hdv, config)
            hdvs.append(hdv)
    road.vehicles.extend(avs)
    road.vehicles.extend(hdvs)
    return avs, hdvs
