"""The compiled road's state array and what every compiled module of it shares: the layout (one
row per vehicle in ``road.vehicles`` order, the columns named below), highway-env's vehicle,
controller and IDM parameters (read once from its classes), and the elementary functions that
round as numpy's.

The road's lanes are data (:mod:`sb3_marl.sim.lanes`: a table read from a highway-env
``RoadNetwork``); static obstacles (highway-env's ``Obstacle``, e.g. the end of a merging lane) are
rows of the array after the vehicles, flagged ``IS_OBSTACLE``: they neither act nor move, but are
seen as leaders and collide as highway-env's objects do. In highway-env's order of operations:
:mod:`sb3_marl.sim.dynamics` steps it (:func:`~sb3_marl.sim.dynamics.policy_step`), with
:mod:`sb3_marl.sim.drivers` (IDM, MOBIL, steering, every vehicle's decision; the rule driver),
:mod:`sb3_marl.sim.collisions` (highway-env's collision test) and :mod:`sb3_marl.sim.meta_actions`
(the AVs' meta-actions and their masks). The env keeps its road as this array (the spawn is
:func:`sb3_marl.sim.spawn.new_episode`), :mod:`sb3_marl.sim.simulator` builds highway-env objects from it
where they are needed, and the parity tests hold it to highway-env's own classes. Only MOBIL's
politeness, safe braking and threshold are read per HDV (the scenario config sets them,
:func:`sb3_marl.sim.road.vehicle_state`).

Exactness: sin, cos and sqrt round as numpy's; numpy's float64 arcsin, arctan, tan and power use
SIMD routines on CPUs that have them (AVX-512 here), which differ from the C library's (used by
compiled code) in the last bit for a few % of inputs, and numpy's small dot products and 2 × 2
matrix products may fuse multiply-adds. Trajectories therefore agree with highway-env to about
1e-12 m per step rather than bit for bit; tests/envs/test_kernel.py checks the tolerance and that
episode outcomes (crashes, lane changes, lengths) are identical.

Units: positions and distances in m, speeds in m/s, accelerations in m/s², angles in rad, time in s.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar, cast

import numba
import numpy as np
from highway_env.road.lane import AbstractLane
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.controller import ControlledVehicle
from highway_env.vehicle.kinematics import Vehicle
from highway_env.vehicle.objects import Obstacle

# highway-env's parameters, read once (numba freezes module globals at compile time)
LENGTH = float(Vehicle.LENGTH)  # [m]
WIDTH = float(Vehicle.WIDTH)  # [m]
DIAGONAL = float(np.sqrt(LENGTH**2 + WIDTH**2))  # [m], as RoadObject.diagonal
MAX_SPEED = float(Vehicle.MAX_SPEED)  # [m/s]
MIN_SPEED = float(Vehicle.MIN_SPEED)  # [m/s]
KP_A = float(ControlledVehicle.KP_A)  # [1/s]
KP_HEADING = float(ControlledVehicle.KP_HEADING)  # [1/s]
KP_LATERAL = float(ControlledVehicle.KP_LATERAL)  # [1/s]
TAU_PURSUIT = float(ControlledVehicle.TAU_PURSUIT)  # [s]
MAX_STEERING_ANGLE = float(ControlledVehicle.MAX_STEERING_ANGLE)  # [rad]
ACC_MAX = float(IDMVehicle.ACC_MAX)  # [m/s²]
COMFORT_ACC_MAX = float(IDMVehicle.COMFORT_ACC_MAX)  # [m/s²]
COMFORT_ACC_MIN = float(IDMVehicle.COMFORT_ACC_MIN)  # [m/s²]
DISTANCE_WANTED = float(IDMVehicle.DISTANCE_WANTED)  # [m]
TIME_WANTED = float(IDMVehicle.TIME_WANTED)  # [s]
DELTA = float(IDMVehicle.DELTA)  # IDM exponent
LANE_CHANGE_DELAY = float(IDMVehicle.LANE_CHANGE_DELAY)  # [s]
LANE_VEHICLE_LENGTH = float(AbstractLane.VEHICLE_LENGTH)  # [m], lanes' end margin
ON_LANE_MARGIN = 1.0  # [m], highway-env's margin of "on the lane" in its neighbour search
OBSTACLE_LENGTH = float(Obstacle.LENGTH)  # [m]
OBSTACLE_WIDTH = float(Obstacle.WIDTH)  # [m]
OBSTACLE_DIAGONAL = float(np.sqrt(OBSTACLE_LENGTH**2 + OBSTACLE_WIDTH**2))  # [m]

#: Columns of the state array, one row per vehicle in ``road.vehicles`` order.
(
    X,
    Y,
    HEADING,
    SPEED,
    LANE,
    TARGET_LANE,
    TARGET_SPEED,
    IS_HDV,
    TIMER,
    CRASHED,
    COLLIDABLE,
    PRESENT,
    IMPACT_X,
    IMPACT_Y,
    HAS_IMPACT,
    STEERING,
    ACCELERATION,
    POLITENESS,
    MAX_BRAKING_IMPOSED,
    MIN_ACC_GAIN,
    IS_OBSTACLE,
    VEHICLE_ID,  # the vehicle's number in its episode (its row at the spawn; -1: an obstacle); never read by the dynamics
    IDM_ACC,  # [m/s²] its IDM comfortable acceleration a (highway-env's COMFORT_ACC_MAX)
    IDM_DECEL,  # [m/s²] its IDM comfortable deceleration b, positive (-COMFORT_ACC_MIN)
    IDM_DISTANCE,  # [m] its IDM jam distance, front to front (DISTANCE_WANTED)
    IDM_TIME,  # [s] its IDM time headway (TIME_WANTED)
) = range(26)
COLUMNS = 26
#: "No vehicle" (a row index of -1) as an int64: numba compiles a function passed the literal -1
#: a second time, for the literal, and a variable started at -1 makes it do so for its callees.
NO_VEHICLE = cast(int, np.int64(-1))

_F = TypeVar("_F", bound=Callable[..., Any])


def jit(function: _F) -> _F:
    """``function`` compiled as every function of the kernel: numba's nopython mode, cached in
    ``NUMBA_CACHE_DIR`` (:mod:`sb3_marl.common.compiled`), without the C callback wrapper numba
    otherwise builds for each function (for first-class function values, which the kernel never
    passes), with numpy's error model (a division by zero gives inf or NaN, as in numpy, where
    Python's model would raise; no kernel function divides by zero where it matters).

    Reference counts: a compiled function takes a reference to each array argument when it starts
    and gives it back after the array's last use, each an atomic operation; numba removes the
    pair only where every path out of the function gives it back in the same way. A function
    called for every vehicle and frame therefore reads its arrays before it branches, leaves by one
    exit where it can (:func:`~sb3_marl.sim.drivers.idm`), and calls nothing that may raise (the
    error model above: a raising path keeps the pair too); where it must call a function that
    numba does not inline, the caller tests first whether the call has work to do
    (:func:`~sb3_marl.sim.drivers.act`). ``tests/envs/test_kernel.py`` checks the machine code of the lane
    helpers and of ``idm``."""
    options: dict[str, Any] = {"cache": True, "no_cfunc_wrapper": True, "error_model": "numpy"}
    return cast(_F, numba.njit(function, **options))


@jit
def sin(angle: float) -> float:
    """``np.sin``; sin(±0) = ±0 exactly without the call (most vehicles drive straight)."""
    return angle if angle == 0 else np.sin(angle)


@jit
def cos(angle: float) -> float:
    """``np.cos``; cos(±0) = 1 exactly without the call."""
    return 1.0 if angle == 0 else np.cos(angle)


@jit
def tan(angle: float) -> float:
    """``np.tan``; tan(±0) = ±0."""
    return angle if angle == 0 else np.tan(angle)


@jit
def arcsin(value: float) -> float:
    """``np.arcsin``; arcsin(±0) = ±0."""
    return value if value == 0 else np.arcsin(value)


@jit
def arctan(value: float) -> float:
    """``np.arctan``; arctan(±0) = ±0."""
    return value if value == 0 else np.arctan(value)


@jit
def not_zero(value: float) -> float:
    """highway-env's ``utils.not_zero`` (eps 1e-2)."""
    if abs(value) > 1e-2:
        return value
    return 1e-2 if value >= 0 else -1e-2


@jit
def wrap_to_pi(angle: float) -> float:
    """highway-env's ``utils.wrap_to_pi`` [rad] (Python's float modulo; skipped where it returns
    its argument exactly, within [0, 2π), which is where almost every angle falls)."""
    shifted = angle + np.pi
    if not 0 <= shifted < 2 * np.pi:
        shifted %= 2 * np.pi
    return shifted - np.pi


@jit
def argsort(values: np.ndarray) -> np.ndarray:
    """``np.argsort(values, kind="stable")`` (equal values in index order) by insertion: the kernel
    sorts a few dozen vehicles at most, and this compiles in a tenth of numba's merge sort's time.
    No NaN (numpy sorts it last; here it stays where it is): the kernel sorts none."""
    order = np.empty(values.size, dtype=np.int64)
    for j in range(values.size):
        k = j
        while k > 0 and values[order[k - 1]] > values[j]:
            order[k] = order[k - 1]
            k -= 1
        order[k] = j
    return order


@jit
def clip(value: float, low: float, high: float) -> float:
    """``np.clip`` of one number: max with ``low``, then min with ``high``."""
    return min(max(value, low), high)
