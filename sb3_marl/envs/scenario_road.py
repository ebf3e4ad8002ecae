"""What the scenarios differ in, as data of a config: the road's geometry, where it ends, and the
merge's rules (:class:`ScenarioRoad`), and highway-env's road for drawing and the stock simulator
(:func:`highway_env_road`). The one scenario env (:class:`~sb3_marl.envs.lane_change_env.LaneChangeEnv`,
the merge's :class:`~sb3_marl.envs.merge_env.MergeEnv` only names its scenario) and its compiled
step read them; a new road is a new entry here. Units: m."""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
from highway_env.road.road import Road

from sb3_marl.envs.config import MERGE
from sb3_marl.envs.merge_rules import ACROSS, ACROSS_FROM, NEXT_ON_ROUTE, ROUTE, MergeRules
from sb3_marl.sim.merge_road import ROAD_LENGTH, make_merge_road, merge_lanes
from sb3_marl.sim.road import highway_lanes, make_road


class ScenarioRoad(NamedTuple):
    """A scenario config's road as the env, its supervisor and its compiled step read it."""

    lanes: np.ndarray  #: the lane table (:func:`~sb3_marl.sim.lanes.lane_table`)
    end: float  #: [m] x past which a vehicle has left the scenario (inf: no end, the merge)
    length: float  #: [m] the road's length, by which the observation normalises the ego's x
    merge: MergeRules | None  #: the merging road's tables and supervisor order (None: the highway)


def scenario_road(config: dict[str, Any], scenario: str) -> ScenarioRoad:
    """The road of a full config of ``scenario`` (:data:`~sb3_marl.envs.config.LANE_CHANGE` or ``MERGE``)."""
    if scenario == MERGE:
        merging_first = config["supervisor_priority"] == "merging"
        rules = MergeRules(ROUTE, ACROSS, ACROSS_FROM, NEXT_ON_ROUTE, merging_first)
        return ScenarioRoad(merge_lanes(float(config["speed_limit"])), np.inf, ROAD_LENGTH, rules)
    length = float(config["road_length"])
    return ScenarioRoad(highway_lanes(config), length, length, None)


def highway_env_road(config: dict[str, Any], scenario: str, np_random: np.random.Generator) -> Road:
    """highway-env's road of a full config of ``scenario``, without vehicles (the merge's with its obstacle)."""
    return (make_merge_road if scenario == MERGE else make_road)(config, np_random)
