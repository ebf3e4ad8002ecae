"""VecEnv wrappers that turn multi-agent scenario envs into ordinary Stable-Baselines3 VecEnvs."""

from wrappers.centralised_state import VecCentralisedState
from wrappers.parameter_sharing import (
    REWARD_MODES,
    VEC_BACKENDS,
    ParameterSharingVecEnv,
)
from wrappers.reward_scale import VecRewardScale

__all__ = ["REWARD_MODES", "VEC_BACKENDS", "ParameterSharingVecEnv", "VecCentralisedState", "VecRewardScale"]
