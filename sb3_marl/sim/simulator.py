"""The road's state array and highway-env's vehicle objects, each built from the other.

The scenario steps its vehicles as one array (:mod:`sb3_marl.sim.kernel`'s columns, one row per
vehicle, AVs first), in compiled code. highway-env's objects (``Road``, ``MDPVehicle`` for the AVs,
``IDMVehicle`` for the HDVs) are built from it only where they are needed: drawing frames, the
hand-written IDM/MOBIL policy, and :data:`STOCK`, the reference that steps highway-env's own classes
frame by frame (the parity tests hold :data:`COMPILED` to it: identical episode events, states
within a rounding tolerance; tests/envs/test_kernel.py, benchmarks/kernel_parity.py).

Units: positions in m, speeds in m/s, angles in rad, time in s.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from highway_env.road.road import Road, RoadNetwork
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.controller import MDPVehicle
from highway_env.vehicle.kinematics import Vehicle
from highway_env.vehicle.objects import RoadObject

from sb3_marl.sim import kernel

#: How the scenario steps: the compiled kernel on the state array (default), or highway-env's own
#: classes frame by frame (the parity reference; also used whenever frames are drawn).
COMPILED, STOCK = "compiled", "stock"
SIMULATORS = (COMPILED, STOCK)
SEGMENT = ("start", "end")  # the highway's one road segment (RoadNetwork node names)


def step_objects(
    road: Road,
    actions: Sequence[str],
    braking: np.ndarray,
    frames: int,
    dt: float,
    road_end: float,
    on_frame: Callable[[int], None],
) -> None:
    """One policy step with highway-env's own classes: the first ``len(actions)`` vehicles of
    ``road`` (the AVs) take their meta-actions (labels; target speed 0 m/s for those ``braking``),
    then ``frames`` frames of ``dt`` s (``Road.act``, ``Road.step``), each followed by
    ``on_frame(frame)``. Past ``road_end`` [m] HDVs are removed and AVs stop colliding."""
    n_avs = len(actions)
    for av, action, brake in zip(road.vehicles, actions, braking):
        av.act(action)
        if brake:
            av.target_speed = 0.0
    for frame in range(frames):
        road.act()
        road.step(dt)
        for av in road.vehicles[:n_avs]:
            av.collidable = av.collidable and av.position[0] <= road_end
        road.vehicles = [v for k, v in enumerate(road.vehicles) if k < n_avs or v.position[0] <= road_end]
        on_frame(frame)


def capture(vehicles: list[Vehicle], network: RoadNetwork, objects: Sequence[RoadObject] = ()) -> np.ndarray:
    """The state array (n, :data:`~sb3_marl.sim.kernel.COLUMNS`) of highway-env vehicles, in order,
    then of the ``objects`` (obstacles); lanes numbered as ``network.lanes_list()``."""
    numbers = {index: number for number, index in enumerate(lane_indices(network))}
    rows = [_row(v, numbers, k) for k, v in enumerate(vehicles)] + [_obstacle_row(o) for o in objects]
    return np.array(rows, dtype=np.float64).reshape(-1, kernel.COLUMNS)


def lane_indices(network: RoadNetwork) -> list[tuple[str, str, int]]:
    """highway-env's lane indices (from, to, id) in the order of ``network.lanes_list()``: lane
    number k of the kernel is ``lane_indices(network)[k]``."""
    return [(start, end, i) for start, ends in network.graph.items() for end, lanes in ends.items() for i in range(len(lanes))]


def _obstacle_row(o: RoadObject) -> tuple:
    row = [0.0] * kernel.COLUMNS
    row[kernel.X], row[kernel.Y] = o.position.tolist()
    row[kernel.HEADING], row[kernel.SPEED] = o.heading, o.speed
    row[kernel.LANE] = row[kernel.TARGET_LANE] = -1
    row[kernel.CRASHED], row[kernel.COLLIDABLE], row[kernel.PRESENT], row[kernel.IS_OBSTACLE] = o.crashed, o.collidable, 1, 1
    row[kernel.VEHICLE_ID] = -1
    return tuple(row)


def _row(v: Vehicle, numbers: dict, k: int) -> tuple:
    """Vehicle ``v``'s row; its ``vehicle_id`` where :func:`vehicle_objects` gave it one, else ``k``."""
    hdv = isinstance(v, IDMVehicle)
    impact = v.impact
    return (
        *v.position.tolist(),
        v.heading,
        v.speed,
        numbers[v.lane_index],
        numbers[v.target_lane_index],
        v.target_speed,
        hdv,
        v.timer if hdv else 0.0,
        v.crashed,
        v.collidable,
        True,
        *((0.0, 0.0) if impact is None else impact.tolist()),
        impact is not None,
        v.action["steering"],
        v.action["acceleration"],
        *((v.POLITENESS, v.LANE_CHANGE_MAX_BRAKING_IMPOSED, v.LANE_CHANGE_MIN_ACC_GAIN) if hdv else (0.0, 0.0, 0.0)),
        False,
        getattr(v, "vehicle_id", k),
        # IDM's parameters: an HDV's own (instance or class), an AV's highway-env's IDMVehicle's
        getattr(v, "COMFORT_ACC_MAX", kernel.COMFORT_ACC_MAX),
        -getattr(v, "COMFORT_ACC_MIN", kernel.COMFORT_ACC_MIN),
        getattr(v, "DISTANCE_WANTED", kernel.DISTANCE_WANTED),
        getattr(v, "TIME_WANTED", kernel.TIME_WANTED),
    )


def vehicle_objects(road: Road, state: np.ndarray, config: dict[str, Any]) -> list[Vehicle]:
    """highway-env vehicles on ``road`` with the vehicle rows of ``state``: ``IDMVehicle`` for the HDV
    rows, ``MDPVehicle`` (on the config's ``target_speeds``) for the others; obstacle rows are the
    road's own ``objects``. :func:`capture` of the result and the road's objects gives ``state``
    back exactly."""
    lanes, indices = road.network.lanes_list(), lane_indices(road.network)
    vehicles: list[Vehicle] = []
    for row in state.tolist():
        if row[kernel.IS_OBSTACLE]:
            continue
        lane, target = indices[int(row[kernel.LANE])], indices[int(row[kernel.TARGET_LANE])]
        position, heading, speed = [row[kernel.X], row[kernel.Y]], row[kernel.HEADING], row[kernel.SPEED]
        v: Vehicle
        if row[kernel.IS_HDV]:
            v = IDMVehicle(road, position, heading, speed, target_lane_index=target)
            v.timer = row[kernel.TIMER]
            v.POLITENESS = row[kernel.POLITENESS]
            v.LANE_CHANGE_MAX_BRAKING_IMPOSED = row[kernel.MAX_BRAKING_IMPOSED]
            v.LANE_CHANGE_MIN_ACC_GAIN = row[kernel.MIN_ACC_GAIN]
            v.COMFORT_ACC_MAX, v.COMFORT_ACC_MIN = row[kernel.IDM_ACC], -row[kernel.IDM_DECEL]
            v.DISTANCE_WANTED, v.TIME_WANTED = row[kernel.IDM_DISTANCE], row[kernel.IDM_TIME]
        else:
            v = MDPVehicle(road, position, heading, speed, target_lane_index=target, target_speeds=config["target_speeds"])
            v.speed_index = v.speed_to_index(row[kernel.TARGET_SPEED])
        v.target_speed = row[kernel.TARGET_SPEED]
        v.lane_index, v.lane = lane, lanes[int(row[kernel.LANE])]
        v.crashed, v.collidable = bool(row[kernel.CRASHED]), bool(row[kernel.COLLIDABLE])
        v.impact = np.array([row[kernel.IMPACT_X], row[kernel.IMPACT_Y]]) if row[kernel.HAS_IMPACT] else None
        v.action = {"steering": row[kernel.STEERING], "acceleration": row[kernel.ACCELERATION]}
        v.vehicle_id = row[kernel.VEHICLE_ID]
        vehicles.append(v)
    return vehicles
