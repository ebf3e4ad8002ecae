"""The on-ramp merging road of Chen et al. (2021), as MARL_CAVs' ``merge_env_v1`` builds it, and its
random spawn.

A one-lane main road along +x at y = 0 (roads a→b, b→c, c→d) and a ramp (j→k straight at
y = 10.5 m, k→b a sine lane that converges to y = 4 m, then the merging lane b→c beside the main
road, lane 1 of road b→c) whose end is blocked by an obstacle. The sections are :data:`ENDS` m
long: the main road before the ramp's converging section, the converging section, the merging
lane, the main road after it. The ramp lanes are ``forbidden`` (no vehicle changes lanes into
them); vehicles leave the merging lane by changing to the main road's lane 0. Units: m, m/s.
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np
from highway_env.road.lane import LineType, SineLane, StraightLane
from highway_env.road.road import Road, RoadNetwork
from highway_env.vehicle.objects import Obstacle

from sb3_marl.sim.lanes import lane_table
from sb3_marl.sim.simulator import capture

ENDS = (220.0, 100.0, 100.0, 100.0)  # [m] the four sections
AMPLITUDE = 3.25  # [m] of the converging sine section
RAMP_Y = 6.5 + 4  # [m] the ramp's straight section, y
MERGE_END = sum(ENDS[:3])  # [m] x of the merging lane's end (the obstacle)
ROAD_LENGTH = sum(ENDS)  # [m] the main road's length
#: Spawn points [m] on the main road and on the ramp (x before the position noise).
MAIN_SPAWN = (10.0, 50.0, 90.0, 130.0, 170.0, 210.0)
RAMP_SPAWN = (5.0, 45.0, 85.0, 125.0, 165.0, 205.0)
SPAWN_SPACING = 40.0  # [m] between spawn points
#: Lane numbers of the lane table (``RoadNetwork.lanes_list`` order).
MAIN_BEFORE, MAIN_BESIDE, MERGING_LANE, MAIN_AFTER, RAMP, CONVERGING = range(6)


def merge_network(speed_limit: float) -> RoadNetwork:
    """``merge_env_v1._make_road``'s network, every lane with ``speed_limit`` [m/s]."""
    network = RoadNetwork()
    c, s, n = LineType.CONTINUOUS_LINE, LineType.STRIPED, LineType.NONE
    ends = ENDS
    network.add_lane("a", "b", StraightLane([0, 0], [sum(ends[:2]), 0], line_types=[c, c], speed_limit=speed_limit))
    network.add_lane(
        "b", "c", StraightLane([sum(ends[:2]), 0], [sum(ends[:3]), 0], line_types=[c, s], speed_limit=speed_limit)
    )
    network.add_lane("c", "d", StraightLane([sum(ends[:3]), 0], [sum(ends), 0], line_types=[c, c], speed_limit=speed_limit))
    ramp = StraightLane([0, RAMP_Y], [ends[0], RAMP_Y], line_types=[c, c], forbidden=True, speed_limit=speed_limit)
    converging = SineLane(
        ramp.position(ends[0], -AMPLITUDE),
        ramp.position(sum(ends[:2]), -AMPLITUDE),
        AMPLITUDE,
        2 * np.pi / (2 * ends[1]),
        np.pi / 2,
        line_types=[c, c],
        forbidden=True,
        speed_limit=speed_limit,
    )
    merging = StraightLane(
        converging.position(ends[1], 0),
        np.add(converging.position(ends[1], 0), [ends[2], 0]),
        line_types=[n, c],
        forbidden=True,
        speed_limit=speed_limit,
    )
    network.add_lane("j", "k", ramp)
    network.add_lane("k", "b", converging)
    network.add_lane("b", "c", merging)
    return network


def make_merge_road(config: dict[str, Any], np_random: np.random.Generator) -> Road:
    """highway-env's merging road of the config with its obstacle, without vehicles."""
    network = merge_network(float(config["speed_limit"]))
    road = Road(network=network, np_random=np_random, record_history=config["show_trajectories"])
    road.objects.append(Obstacle(road, _obstacle_position(network)))
    return road


def _obstacle_position(network: RoadNetwork) -> np.ndarray:
    """[m] where MARL_CAVs puts the obstacle: the merging lane's end."""
    return network.get_lane(("b", "c", 1)).position(ENDS[2], 0)


def merge_lanes(speed_limit: float) -> np.ndarray:
    """The lane table (:func:`~sb3_marl.sim.lanes.lane_table`) of the merging road; read-only, shared."""
    return _merge_lanes(float(speed_limit))


@functools.lru_cache(maxsize=8)
def _merge_lanes(speed_limit: float) -> np.ndarray:
    return lane_table(merge_network(speed_limit))


def obstacle_rows() -> np.ndarray:
    """(1, :data:`~sb3_marl.sim.kernel.COLUMNS`) the obstacle at the merging lane's end, as the
    state array's last row (a new array)."""
    return _obstacle_rows().copy()


@functools.lru_cache(maxsize=1)
def _obstacle_rows() -> np.ndarray:
    network = merge_network(30.0)  # the obstacle's place does not depend on the speed limit
    return capture([], network, [Obstacle(None, _obstacle_position(network))])
