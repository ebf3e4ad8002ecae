"""Road and traffic of the lane-change scenario: a straight one-way highway and a random spawn.

Positions are in m, speeds in m/s. The highway runs along +x from x = 0 to ``road_length``;
lane 0 is at y = 0 and lane k at y = k * lane_width.
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np
from highway_env.road.lane import LineType, StraightLane
from highway_env.road.road import Road, RoadNetwork
from highway_env.vehicle.behavior import IDMVehicle

from sb3_marl.sim import HDV_STYLES, kernel, meta_actions
from sb3_marl.sim.kernel import jit
from sb3_marl.sim.lanes import lane_table
from sb3_marl.sim.simulator import SEGMENT


def make_road(config: dict[str, Any], np_random: np.random.Generator) -> Road:
    """highway-env's road of the config (:func:`highway_network`), without vehicles (see
    :func:`~sb3_marl.sim.simulator.vehicle_objects`).

    :param config: the scenario config
    :param np_random: the env's random generator, shared with the vehicles' behaviour
    """
    network = highway_network(config["lanes_count"], config["lane_width"], config["road_length"], config["speed_limit"])
    return Road(network=network, np_random=np_random, record_history=config["show_trajectories"])


def highway_network(lanes: int, width: float, length: float, speed_limit: float) -> RoadNetwork:
    """highway-env's one-way highway: ``lanes`` straight lanes of ``length`` m along +x from x = 0,
    lane k centred at y = k × ``width`` [m], one road segment."""
    network = RoadNetwork()
    for lane in range(lanes):
        y = lane * width
        line_types = (
            LineType.CONTINUOUS_LINE if lane == 0 else LineType.STRIPED,
            LineType.CONTINUOUS_LINE if lane == lanes - 1 else LineType.NONE,
        )
        network.add_lane(
            *SEGMENT, StraightLane([0.0, y], [length, y], width=width, line_types=line_types, speed_limit=speed_limit)
        )
    return network


def highway_lanes(config: dict[str, Any]) -> np.ndarray:
    """The lane table (:func:`~sb3_marl.sim.lanes.lane_table`) of the config's highway; read-only, shared."""
    return _highway_lanes(
        int(config["lanes_count"]), float(config["lane_width"]), float(config["road_length"]), float(config["speed_limit"])
    )


@functools.lru_cache(maxsize=32)
def _highway_lanes(lanes: int, width: float, length: float, speed_limit: float) -> np.ndarray:
    return lane_table(highway_network(lanes, width, length, speed_limit))


def configure_hdv(vehicle: IDMVehicle, config: dict[str, Any]) -> None:
    """Apply the config's MOBIL parameters and IDM style to one HDV instance, as :func:`vehicle_state`
    gives them to an HDV row.

    :param vehicle: a human-driven vehicle
    :param config: the scenario config (``hdv_politeness``, ``hdv_b_safe`` in m/s²,
        ``hdv_lane_change_threshold`` in m/s², ``hdv_style``)
    """
    vehicle.POLITENESS = float(config["hdv_politeness"])
    vehicle.LANE_CHANGE_MAX_BRAKING_IMPOSED = float(config["hdv_b_safe"])
    vehicle.LANE_CHANGE_MIN_ACC_GAIN = float(config["hdv_lane_change_threshold"])
    a, b, s0, t = HDV_STYLES[config.get("hdv_style", "normal")]
    vehicle.COMFORT_ACC_MAX, vehicle.COMFORT_ACC_MIN, vehicle.DISTANCE_WANTED, vehicle.TIME_WANTED = a, -b, s0, t


def vehicle_state(
    config: dict[str, Any], x: np.ndarray, lane: np.ndarray, speed: np.ndarray, n_avs: int, y: np.ndarray | None = None
) -> np.ndarray:
    """The state array of vehicles placed at (``x``, ``y``) [m] on ``lane`` (lane numbers of the
    road's table; ``y`` by default the lane's centre on the config's highway, lane × ``lane_width``),
    heading along +x at ``speed`` [m/s], the first ``n_avs`` AVs, the others HDVs: the state
    highway-env's ``MDPVehicle`` and ``IDMVehicle`` constructors give them (an AV's target speed is
    the ladder step nearest its speed, an HDV's its speed; the HDV's lane-change timer starts at
    ``(x + y) π mod LANE_CHANGE_DELAY``; the config's MOBIL parameters and IDM style,
    ``hdv_style``; an AV's IDM columns, used where an HDV's MOBIL rates it, are highway-env's)."""
    lane = np.asarray(lane, dtype=np.float64).reshape(-1)
    return vehicle_rows(
        np.asarray(x, dtype=np.float64).reshape(-1),
        lane * float(config["lane_width"]) if y is None else np.asarray(y, dtype=np.float64).reshape(-1),
        lane,
        np.asarray(speed, dtype=np.float64).reshape(-1),
        n_avs,
        np.asarray(config["target_speeds"], dtype=np.float64),
        float(config["hdv_politeness"]),
        float(config["hdv_b_safe"]),
        float(config["hdv_lane_change_threshold"]),
        np.array(HDV_STYLES[config.get("hdv_style", "normal")]),
    )


@jit
def vehicle_rows(
    x: np.ndarray,
    y: np.ndarray,
    lane: np.ndarray,
    speed: np.ndarray,
    n_avs: int,
    ladder: np.ndarray,
    politeness: float,
    max_braking_imposed: float,
    min_acc_gain: float,
    hdv_idm: np.ndarray,
) -> np.ndarray:
    state = np.zeros((x.size, kernel.COLUMNS))
    av_idm = np.array([kernel.COMFORT_ACC_MAX, -kernel.COMFORT_ACC_MIN, kernel.DISTANCE_WANTED, kernel.TIME_WANTED])
    for k in range(x.size):
        state[k, kernel.X], state[k, kernel.Y], state[k, kernel.SPEED] = x[k], y[k], speed[k]
        state[k, kernel.LANE] = state[k, kernel.TARGET_LANE] = lane[k]
        state[k, kernel.COLLIDABLE] = state[k, kernel.PRESENT] = 1.0
        state[k, kernel.VEHICLE_ID] = k
        state[k, kernel.IDM_ACC : kernel.IDM_TIME + 1] = av_idm if k < n_avs else hdv_idm
        if k < n_avs:
            state[k, kernel.TARGET_SPEED] = ladder[meta_actions.speed_index(speed[k], ladder)]
        else:
            state[k, kernel.TARGET_SPEED] = speed[k]
            state[k, kernel.IS_HDV] = 1.0
            state[k, kernel.TIMER] = (x[k] + y[k]) * np.pi % kernel.LANE_CHANGE_DELAY
            state[k, kernel.POLITENESS] = politeness
            state[k, kernel.MAX_BRAKING_IMPOSED] = max_braking_imposed
            state[k, kernel.MIN_ACC_GAIN] = min_acc_gain
    return state
