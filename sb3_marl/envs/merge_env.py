"""The multi-agent on-ramp merging scenario of Chen et al. (2021, arXiv 2105.05701; MARL_CAVs'
``merge_env_v1``): the lane-change scenario's env on the merging road (:mod:`sb3_marl.sim.merge_road`)."""

from __future__ import annotations

from sb3_marl.envs import config as cfg
from sb3_marl.envs.lane_change_env import LaneChangeEnv


class MergeEnv(LaneChangeEnv):
    """On-ramp merging: AVs on the main road and on the ramp, among IDM/MOBIL HDVs; the ramp's AVs
    and HDVs must change to the main road before the merging lane's obstacle.

    Everything of :class:`~sb3_marl.envs.lane_change_env.LaneChangeEnv` holds (actions, masks,
    observation, supervisor, info, ``place`` with the road's lane numbers), with the merging
    paper's differences, all data of the scenario's config and road
    (:func:`~sb3_marl.envs.scenario_road.scenario_road`): the spawn
    (:func:`~sb3_marl.sim.spawn.new_episode`'s spawn points), its densities
    (:data:`~sb3_marl.envs.config.MERGE_DENSITIES`), no road end (vehicles drive on past the road,
    as in MARL_CAVs), the reward ``200·safety + 4·headway + 1·speed + 4·merging-lane cost`` (no
    comfort term by default), the regional neighbour sets of MARL_CAVs' ``_regional_reward``, the
    supervisor's order of service, and the info's ``ramp_av``, ``merge_time`` and ``stranded``.
    """

    scenario = cfg.MERGE
