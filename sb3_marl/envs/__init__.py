"""The lane-change scenario; importing this module registers its gymnasium ids."""

from typing import TYPE_CHECKING, Any

import gymnasium as gym
from gymnasium.envs.registration import register, registry

from sb3_marl.envs.config import DENSITIES, default_config, validate_config

if TYPE_CHECKING:
    from sb3_marl.envs.lane_change_env import LaneChangeEnv

ENV_IDS = {density: f"sb3_marl/LaneChange-density{density}-v0" for density in DENSITIES}

for _density, _env_id in ENV_IDS.items():
    if _env_id not in registry:
        register(
            id=_env_id,
            entry_point="sb3_marl.envs.lane_change_env:LaneChangeEnv",
            kwargs={"density": _density},
        )


def make_scenario(env_id: str, config: dict[str, Any] | None = None, render_mode: str | None = None) -> "LaneChangeEnv":
    """The unwrapped scenario env of ``env_id`` with ``config`` overrides (no gymnasium wrappers:
    the multi-agent runners step it directly)."""
    return gym.make(env_id, config=dict(config or {}), render_mode=render_mode).unwrapped  # type: ignore[return-value]


def __getattr__(name: str) -> Any:
    """``LaneChangeEnv`` and ``ACTIONS`` import highway-env on first use, not with the package
    (the registered ids name their entry point as a string: ``sb3-marl --help`` stays fast)."""
    if name in ("ACTIONS", "LaneChangeEnv"):
        from sb3_marl.envs import lane_change_env

        return getattr(lane_change_env, name)
    if name in ("parallel_env", "LaneChangeParallelEnv"):
        try:
            from sb3_marl.envs import parallel
        except ModuleNotFoundError as error:
            if error.name != "pettingzoo":
                raise
            raise ModuleNotFoundError(
                "sb3_marl.envs.parallel_env needs PettingZoo: pip install 'sb3-marl[pettingzoo]'", name="pettingzoo"
            ) from None
        return getattr(parallel, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def av_counts(env_id: str, config: dict[str, Any] | None = None) -> list[int]:
    """AV counts that cover a scenario id: the fixed ``config["n_avs"]``, else its density's range.

    :raises ValueError: if ``env_id`` is not registered or is not a lane-change scenario
    """
    config = config or {}
    if config.get("n_avs") is not None:
        return [int(config["n_avs"])]
    try:
        spec = gym.spec(env_id)
    except gym.error.Error as error:
        raise ValueError(f"Invalid env {env_id!r}: not a registered gymnasium id ({error}).") from None
    density = config.get("density", (spec.kwargs or {}).get("density"))
    if density not in DENSITIES:
        raise ValueError(
            f"Invalid env {env_id!r}: not a multi-agent lane-change scenario (no traffic density); "
            "use one of the sb3_marl/LaneChange-density{1,2,3}-v0 ids or a factory."
        )
    lo, hi = DENSITIES[density]["avs"]
    return list(range(lo, hi + 1))


def copy_av_counts(env_id: str, config: dict[str, Any] | None = None, n_copies: int | None = None) -> list[int]:
    """AV count of each scenario copy: the density's counts repeated over ``n_copies`` copies
    (default: one copy per count)."""
    counts = av_counts(env_id, config)
    n_copies = len(counts) if n_copies is None else n_copies
    return [counts[k % len(counts)] for k in range(n_copies)]


def av_steps_per_env_step(env_id: str, config: dict[str, Any] | None = None, n_copies: int | None = None) -> float:
    """AV-steps (SB3 timesteps on the parameter-sharing VecEnv) per env step of one copy, on
    average over the copies: 2 / 3 / 5 at densities 1 / 2 / 3 with the default copies."""
    counts = copy_av_counts(env_id, config, n_copies)
    return sum(counts) / len(counts)


__all__ = [
    "ACTIONS",
    "DENSITIES",
    "ENV_IDS",
    "LaneChangeEnv",
    "LaneChangeParallelEnv",
    "av_counts",
    "av_steps_per_env_step",
    "copy_av_counts",
    "default_config",
    "make_scenario",
    "parallel_env",
    "validate_config",
]
