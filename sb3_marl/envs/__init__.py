"""The lane-change scenario; importing this module registers its gymnasium ids."""

from gymnasium.envs.registration import register, registry

from sb3_marl.envs.config import DENSITIES, default_config, validate_config
from sb3_marl.envs.lane_change_env import ACTIONS, LaneChangeEnv

ENV_IDS = {density: f"sb3_marl/LaneChange-density{density}-v0" for density in DENSITIES}

for _density, _env_id in ENV_IDS.items():
    if _env_id not in registry:
        register(
            id=_env_id,
            entry_point="sb3_marl.envs.lane_change_env:LaneChangeEnv",
            kwargs={"density": _density},
        )

__all__ = ["ACTIONS", "DENSITIES", "ENV_IDS", "LaneChangeEnv", "default_config", "validate_config"]
