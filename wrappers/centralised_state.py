"""VecCentralisedState: each AV slot also observes its scenario copy's global state (CTDE).

Centralised training with decentralised execution: the actor keeps the AV's own view, a
centralised critic (:class:`sb3_marl.algos.common.policies.CentralisedCriticPolicy`) reads the global state.
"""

from __future__ import annotations

import numpy as np
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper
from stable_baselines3.common.vec_env.base_vec_env import VecEnvStepReturn

from sb3_marl.envs.observation import LOCAL_KEY, STATE_KEY, centralised_observation_space, centralised_observations
from wrappers.parameter_sharing import ParameterSharingVecEnv


class VecCentralisedState(VecEnvWrapper):
    """Dict observations ``{"observation": the AV's view, "state": its copy's global state}`` on a
    :class:`~wrappers.ParameterSharingVecEnv` (see
    :func:`~sb3_marl.envs.observation.centralised_observations`); ``terminal_observation`` too.

    :param venv: the parameter-sharing VecEnv (directly, not behind another wrapper)
    :param max_avs: AV slots of the state: the density's largest AV count, so that every copy and
        every evaluation episode of the density shares one state shape
    """

    def __init__(self, venv: VecEnv, max_avs: int) -> None:
        if not isinstance(venv, ParameterSharingVecEnv):
            raise TypeError(f"VecCentralisedState wraps a ParameterSharingVecEnv, got {type(venv).__name__}.")
        if max(venv.n_avs) > max_avs:
            raise ValueError(f"Invalid max_avs={max_avs}: a copy has {max(venv.n_avs)} AVs.")
        super().__init__(venv, observation_space=centralised_observation_space(venv.observation_space, max_avs))  # type: ignore[arg-type]
        self.max_avs = max_avs
        self.slices: list[slice] = venv.slices

    def _with_state(self, obs: np.ndarray) -> dict[str, np.ndarray]:
        state = np.concatenate([centralised_observations(obs[sl], self.max_avs)[STATE_KEY] for sl in self.slices])
        return {LOCAL_KEY: obs, STATE_KEY: state}

    def reset(self) -> dict[str, np.ndarray]:
        return self._with_state(self.venv.reset())  # type: ignore[arg-type]

    def step_wait(self) -> VecEnvStepReturn:
        obs, rewards, dones, infos = self.venv.step_wait()
        for sl in self.slices:
            if dones[sl.start]:  # a copy's slots end together
                final = centralised_observations(
                    np.stack([infos[i]["terminal_observation"] for i in range(sl.start, sl.stop)]), self.max_avs
                )
                for agent, info in enumerate(infos[sl]):
                    info["terminal_observation"] = {key: value[agent] for key, value in final.items()}
        return self._with_state(obs), rewards, dones, infos  # type: ignore[arg-type]
