"""The road's state array and highway-env's vehicle objects, each built from the other.

The scenario steps its vehicles as one array (:mod:`sb3_marl.envs.kernel`'s columns, one row per
vehicle, AVs first), in compiled code. highway-env's objects (``Road``, ``MDPVehicle`` for the AVs,
``IDMVehicle`` for the HDVs) are built from it only where they are needed: drawing frames, the
hand-written IDM/MOBIL policy, and :data:`STOCK`, the reference that steps highway-env's own classes
frame by frame (the parity tests hold :data:`COMPILED` to it: identical episode events, states
within a rounding tolerance; tests/envs/test_kernel.py, benchmarks/kernel_parity.py).

Units: positions in m, speeds in m/s, angles in rad, time in s.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from highway_env.road.road import Road
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.controller import MDPVehicle
from highway_env.vehicle.kinematics import Vehicle

from sb3_marl.envs import kernel

#: How the scenario steps: the compiled kernel on the state array (default), or highway-env's own
#: classes frame by frame (the parity reference; also used whenever frames are drawn).
COMPILED, STOCK = "compiled", "stock"
SIMULATORS = (COMPILED, STOCK)
SEGMENT = ("start", "end")  # the highway's one road segment (RoadNetwork node names)


def capture(vehicles: list[Vehicle]) -> np.ndarray:
    """The state array (n, :data:`~sb3_marl.envs.kernel.COLUMNS`) of highway-env vehicles, in order."""
    return np.array([_row(v) for v in vehicles], dtype=np.float64).reshape(-1, kernel.COLUMNS)


def _row(v: Vehicle) -> tuple:
    hdv = isinstance(v, IDMVehicle)
    impact = v.impact
    return (
        *v.position.tolist(),
        v.heading,
        v.speed,
        v.lane_index[2],
        v.target_lane_index[2],
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
    )


def vehicle_objects(road: Road, state: np.ndarray, config: dict[str, Any]) -> list[Vehicle]:
    """highway-env vehicles on ``road`` with the rows of ``state``: ``IDMVehicle`` for the HDV rows,
    ``MDPVehicle`` (on the config's ``target_speeds``) for the others; :func:`capture` of the
    result gives ``state`` back exactly."""
    lanes = road.network.lanes_list()
    vehicles: list[Vehicle] = []
    for row in state.tolist():
        lane, target = (*SEGMENT, int(row[kernel.LANE])), (*SEGMENT, int(row[kernel.TARGET_LANE]))
        position, heading, speed = [row[kernel.X], row[kernel.Y]], row[kernel.HEADING], row[kernel.SPEED]
        v: Vehicle
        if row[kernel.IS_HDV]:
            v = IDMVehicle(road, position, heading, speed, target_lane_index=target)
            v.timer = row[kernel.TIMER]
            v.POLITENESS = row[kernel.POLITENESS]
            v.LANE_CHANGE_MAX_BRAKING_IMPOSED = row[kernel.MAX_BRAKING_IMPOSED]
            v.LANE_CHANGE_MIN_ACC_GAIN = row[kernel.MIN_ACC_GAIN]
        else:
            v = MDPVehicle(road, position, heading, speed, target_lane_index=target, target_speeds=config["target_speeds"])
            v.speed_index = v.speed_to_index(row[kernel.TARGET_SPEED])
        v.target_speed = row[kernel.TARGET_SPEED]
        v.lane_index, v.lane = lane, lanes[lane[2]]
        v.crashed, v.collidable = bool(row[kernel.CRASHED]), bool(row[kernel.COLLIDABLE])
        v.impact = np.array([row[kernel.IMPACT_X], row[kernel.IMPACT_Y]]) if row[kernel.HAS_IMPACT] else None
        v.action = {"steering": row[kernel.STEERING], "acceleration": row[kernel.ACCELERATION]}
        vehicles.append(v)
    return vehicles
