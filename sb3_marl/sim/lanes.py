"""The road as data the compiled kernel reads: one row per lane of a highway-env ``RoadNetwork``
(:func:`lane_table`), and highway-env's lane geometry on that table, compiled: local coordinates,
headings, positions, "on the lane", reachability, the closest lane and the lane that follows at a
lane's end (``StraightLane``, ``SineLane``, ``RoadNetwork``).

Lanes are numbered in the network's order (``RoadNetwork.lanes_list``); the state array's
``LANE`` and ``TARGET_LANE`` columns hold these numbers. A *road* is a network edge (from, to) with
its lanes side by side; a lane's left and right neighbours are the lanes of its road with the id one
lower and one higher. Every lane is straight, or sine-shaped around a straight base (the merging
ramp). Units: m, rad.
"""

from __future__ import annotations

import numpy as np
from highway_env.road.lane import SineLane, StraightLane
from highway_env.road.road import RoadNetwork

from sb3_marl.sim.kernel import LANE_VEHICLE_LENGTH, TARGET_LANE, X, Y, jit, wrap_to_pi

#: Columns of the lane table.
(
    START_X,  # [m] the (base line's) start
    START_Y,
    DIRECTION_X,  # unit vector along the base line
    DIRECTION_Y,
    LENGTH,  # [m] along the base line
    WIDTH,  # [m]
    HEADING,  # [rad] of the base line
    AMPLITUDE,  # [m] of a sine lane (0: straight)
    PULSATION,  # [rad/m]
    PHASE,  # [rad]
    FORBIDDEN,  # 1: no lane change may target it (highway-env's ``forbidden``)
    ROAD,  # index of its road (network edge)
    LEFT,  # lane number of its left / right neighbour on the road (-1: none)
    RIGHT,
    ROAD_LANES,  # lanes of its road
    LANE_ID,  # its index on the road (highway-env's lane_index[2])
    NEXT_FIRST,  # first lane of the road that follows its end (-1: none), the next road's lanes
    NEXT_COUNT,
    SINE,  # 1: sine lane
) = range(19)
LANE_COLUMNS = 19


def lane_table(network: RoadNetwork) -> np.ndarray:
    """(lanes, :data:`LANE_COLUMNS`) the lanes of ``network`` in its order; read-only.

    Each road (from, to) may be followed by at most one road (from ``to``): the two roads of the
    scenarios are chains."""
    roads = [(start, end) for start, ends in network.graph.items() for end in ends]
    first = {}
    for start, end in roads:
        first[(start, end)] = sum(len(network.graph[a][b]) for a, b in roads[: roads.index((start, end))])
    rows = []
    for road, (start, end) in enumerate(roads):
        lanes = network.graph[start][end]
        following = list(network.graph.get(end, {}))
        if len(following) > 1:
            raise ValueError(f"Invalid road {start!r} -> {end!r}: the kernel follows at most one next road, got {following}.")
        next_first, next_count = (first[(end, following[0])], len(network.graph[end][following[0]])) if following else (-1, 0)
        for lane_id, lane in enumerate(lanes):
            if not isinstance(lane, (StraightLane, SineLane)):
                raise ValueError(f"Invalid lane {(start, end, lane_id)}: the kernel reads straight and sine lanes only.")
            sine = isinstance(lane, SineLane)
            number = first[(start, end)] + lane_id
            rows.append(
                (
                    *lane.start.tolist(),
                    *lane.direction.tolist(),
                    lane.length,
                    lane.width,
                    lane.heading,
                    lane.amplitude if sine else 0.0,
                    lane.pulsation if sine else 0.0,
                    lane.phase if sine else 0.0,
                    lane.forbidden,
                    road,
                    number - 1 if lane_id > 0 else -1,
                    number + 1 if lane_id < len(lanes) - 1 else -1,
                    len(lanes),
                    lane_id,
                    next_first,
                    next_count,
                    sine,
                )
            )
    table = np.array(rows, dtype=np.float64)
    table.setflags(write=False)
    return table


@jit
def local_coordinates(lanes: np.ndarray, lane: int, x: float, y: float) -> tuple[float, float]:
    """``lane.local_coordinates((x, y))``: (longitudinal, lateral) [m] of a point in the lane's frame."""
    start_x, start_y, ux, uy = lanes[lane, START_X], lanes[lane, START_Y], lanes[lane, DIRECTION_X], lanes[lane, DIRECTION_Y]
    sine, amplitude, pulsation, phase = lanes[lane, SINE], lanes[lane, AMPLITUDE], lanes[lane, PULSATION], lanes[lane, PHASE]
    dx, dy = x - start_x, y - start_y
    longitudinal = dx * ux + dy * uy
    lateral = dx * -uy + dy * ux
    if sine:
        lateral -= amplitude * np.sin(pulsation * longitudinal + phase)
    return longitudinal, lateral


@jit
def heading_at(lanes: np.ndarray, lane: int, longitudinal: float) -> float:
    """``lane.heading_at(longitudinal)`` [rad]."""
    heading, sine = lanes[lane, HEADING], lanes[lane, SINE]
    amplitude, pulsation, phase = lanes[lane, AMPLITUDE], lanes[lane, PULSATION], lanes[lane, PHASE]
    if sine:
        heading += np.arctan(amplitude * pulsation * np.cos(pulsation * longitudinal + phase))
    return heading


@jit
def position(lanes: np.ndarray, lane: int, longitudinal: float, lateral: float) -> tuple[float, float]:
    """``lane.position(longitudinal, lateral)``: the world point [m]."""
    start_x, start_y, ux, uy = lanes[lane, START_X], lanes[lane, START_Y], lanes[lane, DIRECTION_X], lanes[lane, DIRECTION_Y]
    sine, amplitude, pulsation, phase = lanes[lane, SINE], lanes[lane, AMPLITUDE], lanes[lane, PULSATION], lanes[lane, PHASE]
    if sine:
        lateral += amplitude * np.sin(pulsation * longitudinal + phase)
    return start_x + longitudinal * ux + lateral * -uy, start_y + longitudinal * uy + lateral * ux


@jit
def on_lane(lanes: np.ndarray, lane: int, x: float, y: float, margin: float) -> bool:
    """``lane.on_lane((x, y), margin=margin)``."""
    longitudinal, lateral = local_coordinates(lanes, lane, x, y)
    return on_lane_at(lanes, lane, longitudinal, lateral, margin)


@jit
def on_lane_at(lanes: np.ndarray, lane: int, longitudinal: float, lateral: float, margin: float) -> bool:
    """:func:`on_lane` of a point at local coordinates (longitudinal, lateral) [m] of ``lane``."""
    width, length = lanes[lane, WIDTH], lanes[lane, LENGTH]
    return abs(lateral) <= width / 2 + margin and (-LANE_VEHICLE_LENGTH <= longitudinal < length + LANE_VEHICLE_LENGTH)


@jit
def reachable_from(lanes: np.ndarray, lane: int, x: float, y: float) -> bool:
    """``lane.is_reachable_from((x, y))``: not forbidden, within two widths laterally, not behind its
    start nor past its end (``lane`` -1: False)."""
    if lane < 0 or lanes[lane, FORBIDDEN]:
        return False
    longitudinal, lateral = local_coordinates(lanes, lane, x, y)
    return abs(lateral) <= 2 * lanes[lane, WIDTH] and 0 <= longitudinal < lanes[lane, LENGTH] + LANE_VEHICLE_LENGTH


@jit
def _distance(lanes: np.ndarray, lane: int, x: float, y: float) -> float:
    """``lane.distance((x, y))`` [m]: lateral offset plus how far the point is before or past the lane."""
    longitudinal, lateral = local_coordinates(lanes, lane, x, y)
    return abs(lateral) + max(longitudinal - lanes[lane, LENGTH], 0.0) + max(0 - longitudinal, 0.0)


@jit
def closest_lane(lanes: np.ndarray, x: float, y: float, heading: float) -> int:
    """``RoadNetwork.get_closest_lane_index``: the first lane of least ``distance_with_heading``
    (heading weight 1 m/rad)."""
    best, best_distance = 0, np.inf
    for lane in range(lanes.shape[0]):
        longitudinal, lateral = local_coordinates(lanes, lane, x, y)
        angle = abs(wrap_to_pi(heading - heading_at(lanes, lane, longitudinal)))
        distance = abs(lateral) + max(longitudinal - lanes[lane, LENGTH], 0.0) + max(0 - longitudinal, 0.0) + 1.0 * angle
        if lane == 0 or distance < best_distance:
            best, best_distance = lane, distance
    return best


@jit
def follow(lanes: np.ndarray, lane: int, x: float, y: float) -> int:
    """``ControlledVehicle.follow_road``: the target lane of a vehicle at (x, y) [m] aiming at
    ``lane``; past the lane's end (``after_end``) the next road's lane (``RoadNetwork.next_lane``
    without a route: the same lane id if the roads have as many lanes, else the lane closest to
    the point projected on the lane's centre), otherwise ``lane``."""
    longitudinal, _ = local_coordinates(lanes, lane, x, y)
    first = int(lanes[lane, NEXT_FIRST])
    if not longitudinal > lanes[lane, LENGTH] - LANE_VEHICLE_LENGTH / 2 or first < 0:
        return lane
    count = int(lanes[lane, NEXT_COUNT])
    if count == lanes[lane, ROAD_LANES]:
        return first + int(lanes[lane, LANE_ID])
    px, py = position(lanes, lane, longitudinal, 0.0)
    best, best_distance = first, np.inf
    for candidate in range(first, first + count):
        distance = _distance(lanes, candidate, px, py)
        if distance < best_distance:
            best, best_distance = candidate, distance
    return best


@jit
def centre_y(lanes: np.ndarray, lane: np.ndarray, x: np.ndarray) -> np.ndarray:
    """y [m] of the centre of each ``lane`` where its base line is at each ``x`` [m] (a lane along +x)."""
    y = np.empty(x.size)
    for k in range(x.size):
        y[k] = position(lanes, lane[k], x[k] - lanes[lane[k], START_X], 0.0)[1]
    return y


@jit
def lane_changes(lanes: np.ndarray, before: np.ndarray, state: np.ndarray) -> np.ndarray:
    """(n,) bool: which of the first ``before.size`` vehicles of ``state`` started a lane change since
    their target lanes were ``before``: a new target lane other than the road's own continuation of
    the old one (:func:`follow` at the vehicle's position)."""
    changed = np.zeros(before.size, dtype=np.bool_)
    for i in range(before.size):
        target = int(state[i, TARGET_LANE])
        changed[i] = target != before[i] and target != follow(lanes, int(before[i]), state[i, X], state[i, Y])
    return changed
