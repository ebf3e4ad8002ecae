"""Hand-written AV policies used as references: uniformly random, cruise and IDM/MOBIL-driven."""

from __future__ import annotations

import numpy as np

from sb3_marl.envs.lane_change_env import ACTION_INDEX, LaneChangeEnv


class RandomPolicy:
    """Each AV's meta-action uniformly among its available ones (the env's action mask), drawn
    from numpy's global generator, which the episode runner seeds per episode
    (:func:`sb3_marl.evaluation.run_episodes`): the same episode seed gives the same actions under
    either supervisor protocol."""

    def __call__(self, env: LaneChangeEnv, obs: np.ndarray) -> np.ndarray:
        masks = env.action_masks()
        scores = np.random.random_sample(masks.shape)
        return np.where(masks, scores, -1.0).argmax(axis=1)


class CruisePolicy:
    """IDLE for every AV at every step: each AV keeps its lane and the target speed it spawned with
    (the speed ladder's value nearest its initial 25-30 m/s). The simplest comfortable policy; with
    the safety supervisor on, the supervisor alone brakes it before a predicted collision."""

    def __call__(self, env: LaneChangeEnv, obs: np.ndarray) -> np.ndarray:
        return np.full(env.n_avs, ACTION_INDEX["IDLE"])


class IDMMobilPolicy:
    """The meta-actions a human driver of the scenario (IDM + MOBIL) would pick in each AV's place:
    the env's compiled rule driver (:meth:`~sb3_marl.envs.lane_change_env.LaneChangeEnv.rule_actions`;
    FASTER / SLOWER beyond the config's ``rule_acceleration_threshold``, m/s²)."""

    def __call__(self, env: LaneChangeEnv, obs: np.ndarray) -> np.ndarray:
        return env.rule_actions()


BASELINES: dict[str, type[RandomPolicy | CruisePolicy | IDMMobilPolicy]] = {
    "random": RandomPolicy,
    "cruise": CruisePolicy,
    "idm-mobil": IDMMobilPolicy,
}
