"""The training rewards of a parameter-sharing VecEnv: scaled, and lowered where the safety
supervisor overruled the proposal (:class:`VecRewardScale`)."""

from __future__ import annotations

from typing import Any

from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper
from stable_baselines3.common.vec_env.base_vec_env import VecEnvStepReturn

from sb3_marl.common.checks import check_number
from wrappers.step_arrays import step_arrays_of


def check_penalty(penalty: float, name: str = "penalty") -> None:
    """A ValueError naming ``name`` unless ``penalty`` is a finite number >= 0."""
    check_number(name, penalty, 0)


def check_reward_scale(scale: float, name: str = "scale") -> None:
    """A reward scale must be a finite number > 0; a ValueError naming ``name`` otherwise."""
    check_number(name, scale, 0, low_open=True, expected="a number > 0")


class VecRewardScale(VecEnvWrapper):
    """The training rewards: ``(reward - intervention_penalty * intervened) * scale``.

    ``scale``: the MARL_CAVs code trains on rewards / 20. ``intervention_penalty`` (not the paper's,
    default 0) lowers the reward of each AV slot whose proposed action the safety supervisor
    replaced (the parameter-sharing VecEnv's ``step_arrays.intervened``), in the paper's units: a
    training signal that the proposal was unsafe (the learner stores the proposed action, so
    without it the supervisor's braking reaches that proposal only through its consequences).
    The step arrays and infos keep the unscaled, unpenalised values (``reward``, ``episode``), so
    metrics stay in the paper's units, and evaluation uses the paper's reward.

    :param venv: the VecEnv to wrap
    :param scale: the factor, > 0
    :param intervention_penalty: >= 0
    """

    def __init__(self, venv: VecEnv, scale: float = 1.0, intervention_penalty: float = 0.0) -> None:
        check_reward_scale(scale)
        check_penalty(intervention_penalty, "intervention_penalty")
        super().__init__(venv)
        self.scale = float(scale)
        self.intervention_penalty = float(intervention_penalty)

    def reset(self) -> Any:
        return self.venv.reset()

    def step_wait(self) -> VecEnvStepReturn:
        obs, rewards, dones, infos = self.venv.step_wait()
        if self.intervention_penalty:
            arrays = step_arrays_of(self.venv)
            if arrays is not None:
                rewards = rewards - self.intervention_penalty * arrays.intervened
        return obs, rewards * self.scale, dones, infos
