"""Hand-written AV policies used as references: uniformly random, cruise and IDM/MOBIL-driven."""

from __future__ import annotations

import numpy as np
from highway_env.vehicle.behavior import IDMVehicle

from sb3_marl.envs.lane_change_env import ACTION_INDEX, LaneChangeEnv
from sb3_marl.envs.road import configure_hdv


class RandomPolicy:
    """Uniformly random meta-actions (all 5, masked or not), from its own seeded generator."""

    def __init__(self, seed: int = 0) -> None:
        self.rng = np.random.default_rng(seed)

    def __call__(self, env: LaneChangeEnv, obs: np.ndarray) -> np.ndarray:
        return self.rng.integers(0, len(ACTION_INDEX), size=env.n_avs)


class CruisePolicy:
    """IDLE for every AV at every step: each AV keeps its lane and the target speed it spawned with
    (the speed ladder's value nearest its initial 25-30 m/s). The simplest comfortable policy; with
    the safety supervisor on, the supervisor alone brakes it before a predicted collision."""

    def __call__(self, env: LaneChangeEnv, obs: np.ndarray) -> np.ndarray:
        return np.full(env.n_avs, ACTION_INDEX["IDLE"])


class IDMMobilPolicy:
    """The meta-actions a human driver of the scenario (IDM + MOBIL) would pick in each AV's place.

    For each AV, an ``IDMVehicle`` with the AV's state and the config's MOBIL parameters, aiming
    at ``speed_limit``, temporarily takes the AV's place on the road: a lane change MOBIL accepts
    becomes LANE_LEFT / LANE_RIGHT; otherwise the IDM acceleration gives FASTER above
    ``+acceleration_threshold``, SLOWER below ``-acceleration_threshold`` (m/s²), else IDLE.

    :param acceleration_threshold: [m/s²] IDM acceleration that triggers a speed change
    """

    def __init__(self, acceleration_threshold: float = 1.0) -> None:
        self.acceleration_threshold = acceleration_threshold

    def __call__(self, env: LaneChangeEnv, obs: np.ndarray) -> np.ndarray:
        mask = env.action_masks()
        return np.array([self._decide(env, i, av, mask[i]) for i, av in enumerate(env.avs)])

    def _decide(self, env: LaneChangeEnv, index: int, av, mask: np.ndarray) -> int:
        road = env.road
        driver = IDMVehicle.create_from(av)
        configure_hdv(driver, env.config)
        driver.target_speed = env.config["speed_limit"]
        slot = road.vehicles.index(av)
        road.vehicles[slot] = driver  # so that neighbour searches see the driver, not the AV
        try:
            if av.lane_index == av.target_lane_index and abs(av.speed) >= 1:
                for side in road.network.side_lanes(av.lane_index):
                    action = ACTION_INDEX["LANE_LEFT" if side[2] < av.lane_index[2] else "LANE_RIGHT"]
                    if mask[action] and driver.mobil(side):
                        return action
            front, rear = road.neighbour_vehicles(driver, driver.lane_index)
            acceleration = driver.acceleration(driver, front, rear)
        finally:
            road.vehicles[slot] = av
        if acceleration > self.acceleration_threshold and mask[ACTION_INDEX["FASTER"]]:
            return ACTION_INDEX["FASTER"]
        if acceleration < -self.acceleration_threshold and mask[ACTION_INDEX["SLOWER"]]:
            return ACTION_INDEX["SLOWER"]
        return ACTION_INDEX["IDLE"]


BASELINES = {"random": RandomPolicy, "cruise": CruisePolicy, "idm-mobil": IDMMobilPolicy}
