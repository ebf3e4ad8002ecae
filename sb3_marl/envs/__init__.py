"""The scenarios (the lane change, the on-ramp merge); importing this module registers their gymnasium ids."""

from typing import TYPE_CHECKING, Any

import gymnasium as gym
from gymnasium.envs.registration import register, registry

from sb3_marl.envs.config import DENSITIES, LANE_CHANGE, MERGE, SCENARIO_DENSITIES, default_config, validate_config

if TYPE_CHECKING:
    from sb3_marl.envs.lane_change_env import LaneChangeEnv

ENV_IDS = {density: f"sb3_marl/LaneChange-density{density}-v0" for density in DENSITIES}
MERGE_ENV_IDS = {density: f"sb3_marl/Merge-density{density}-v0" for density in SCENARIO_DENSITIES[MERGE]}
#: Every scenario id, the lane change's first.
SCENARIO_IDS = [*ENV_IDS.values(), *MERGE_ENV_IDS.values()]
#: The scenario of each registered entry point.
ENTRY_POINTS = {
    "sb3_marl.envs.lane_change_env:LaneChangeEnv": LANE_CHANGE,
    "sb3_marl.envs.merge_env:MergeEnv": MERGE,
}

for _entry_point, _ids in zip(ENTRY_POINTS, (ENV_IDS, MERGE_ENV_IDS)):
    for _density, _env_id in _ids.items():
        if _env_id not in registry:
            register(id=_env_id, entry_point=_entry_point, kwargs={"density": _density})


def scenario_of(env_id: str) -> str:
    """The scenario (:data:`~sb3_marl.envs.config.LANE_CHANGE` or ``MERGE``) of a registered id.

    :raises ValueError: if ``env_id`` is not registered or is not one of the scenarios
    """
    try:
        spec = gym.spec(env_id)
    except gym.error.Error as error:
        raise ValueError(f"Invalid env {env_id!r}: not a registered gymnasium id ({error}).") from None
    scenario = ENTRY_POINTS.get(str(spec.entry_point))
    if scenario is None:
        raise ValueError(
            f"Invalid env {env_id!r}: not a multi-agent scenario of sb3-marl; use one of {SCENARIO_IDS} or a factory."
        )
    return scenario


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
    if name in ("parallel_env", "ScenarioParallelEnv", "LaneChangeParallelEnv"):
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
    densities = SCENARIO_DENSITIES[scenario_of(env_id)]
    density = config.get("density", (gym.spec(env_id).kwargs or {}).get("density"))
    if density not in densities:
        raise ValueError(f"Invalid config['density'] = {density!r} for {env_id!r}: expected one of {sorted(densities)}.")
    lo, hi = densities[density]["avs"]
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
    "MERGE_ENV_IDS",
    "SCENARIO_IDS",
    "LaneChangeEnv",
    "LaneChangeParallelEnv",
    "ScenarioParallelEnv",
    "av_counts",
    "av_steps_per_env_step",
    "copy_av_counts",
    "default_config",
    "make_scenario",
    "parallel_env",
    "scenario_of",
    "validate_config",
]
