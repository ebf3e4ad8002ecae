"""The multi-agent on-ramp merging scenario of Chen et al. (2021, arXiv 2105.05701; MARL_CAVs'
``merge_env_v1``) on the lane-change scenario's machinery: the same kernel, meta-actions, masks,
observation, supervisor and info, on the merging road (:mod:`sb3_marl.sim.merge_road`)."""

from __future__ import annotations

from typing import Any

import numpy as np
from highway_env.road.road import Road

from sb3_marl.envs import config as cfg
from sb3_marl.envs.lane_change_env import LaneChangeEnv
from sb3_marl.envs.merge_rules import ACROSS, ACROSS_FROM, NEXT_ON_ROUTE, ROUTE, MergeRules
from sb3_marl.sim import kernel
from sb3_marl.sim.merge_road import (
    MERGING_LANE,
    ROAD_LENGTH,
    make_merge_road,
    merge_lanes,
)


class MergeEnv(LaneChangeEnv):
    """On-ramp merging: AVs on the main road and on the ramp, among IDM/MOBIL HDVs; the ramp's AVs
    and HDVs must change to the main road before the merging lane's obstacle.

    Everything of :class:`~sb3_marl.envs.lane_change_env.LaneChangeEnv` holds (actions, masks,
    observation, supervisor, info, ``place`` with the road's lane numbers), with the merging
    paper's differences: the spawn (:func:`~sb3_marl.sim.spawn.new_episode`'s spawn points), its densities
    (:data:`~sb3_marl.envs.config.MERGE_DENSITIES`), no road end (vehicles drive on past the road,
    as in MARL_CAVs), the reward ``200·safety + 4·headway + 1·speed + 4·merging-lane cost`` (no
    comfort term by default) and the regional neighbour sets of MARL_CAVs' ``_regional_reward``.
    """

    scenario = cfg.MERGE

    @classmethod
    def default_config(cls) -> dict[str, Any]:
        return cfg.merge_default_config()

    def _road_data(self) -> tuple[np.ndarray, float]:
        return merge_lanes(float(self.config["speed_limit"])), np.inf

    def _make_road(self) -> Road:
        return make_merge_road(self.config, self.np_random)

    @property
    def road_length(self) -> float:
        return ROAD_LENGTH

    def _merge_rules(self) -> MergeRules | None:
        return MergeRules(ROUTE, ACROSS, ACROSS_FROM, NEXT_ON_ROUTE, self.config["supervisor_priority"] == "merging")

    def _scenario_info(self, info: dict[str, Any]) -> None:
        """The merge's info: ``ramp_av`` (the AV started on the ramp), ``merge_time`` [s] (when a
        ramp AV reached the main road; NaN: not yet) and ``stranded`` (vehicles at a standstill,
        under 1 m/s, on the merging lane)."""
        state, n, roads, slots = self.state, self.n_avs, self._roads, self._roads.slots(self._k)
        lane = state[:n, kernel.LANE].astype(np.int64)
        if self.steps == 0:  # a new situation (reset, place)
            roads.new_situation(slots, lane)
        else:
            roads.record_merges(slots, lane, np.full(n, self.steps_done), self.config["policy_frequency"])
        info["ramp_av"], info["merge_time"] = roads.ramp_av[slots].copy(), roads.merge_time[slots].copy()
        stranded = (
            (state[:, kernel.LANE] == MERGING_LANE) & (state[:, kernel.SPEED] < 1.0) & (state[:, kernel.IS_OBSTACLE] == 0)
        )
        info["stranded"] = int(np.count_nonzero(stranded))
