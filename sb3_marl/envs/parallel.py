"""The scenarios (the lane change, the on-ramp merge) as a PettingZoo ``ParallelEnv`` (the ``pettingzoo`` extra).

RLlib, BenchMARL, TorchRL, EPyMARL and SuperSuit accept PettingZoo's parallel API; this module
puts the same :class:`~sb3_marl.envs.lane_change_env.LaneChangeEnv` behind it:

- agents ``"av_0" ... "av_{n-1}"``, one per AV (``n_avs``, default: the density's maximum); all
  of them stay in ``agents`` until the episode ends, which happens for every AV at once (any AV
  crashes: ``terminations`` all True; time limit or every AV past the road end: ``truncations``
  all True); after that ``agents`` is empty, as PettingZoo requires;
- per-agent spaces (cached: ``observation_space(a) is observation_space(a)``): a Box of shape
  (``obs_vehicles_count``, 5), the AV's own kinematic observation, and ``Discrete(5)``, the
  meta-actions (0 LANE_LEFT, 1 IDLE, 2 LANE_RIGHT, 3 FASTER, 4 SLOWER);
- per-agent rewards in ``reward_mode``: ``"local"`` (the paper's neighbourhood average, default),
  ``"global"`` (mean over all AVs) or ``"individual"`` (the AV's own);
- ``infos[agent]["action_mask"]``: the AV's available meta-actions (int8, 1 = available), where
  PettingZoo's masked environments without dict observations put it (in the observation instead
  with ``action_mask_in_observation``), with the AV's speed [m/s],
  headway [m], crash flag and, with the safety supervisor on, its proposed and executed action;
- ``state()``: the global view, all AVs' observations stacked (``state_space``, shape
  (n_avs * obs_vehicles_count * 5,)), for centralised critics;
- ``render()``: highway-env's renderer (``render_mode="rgb_array"`` works headless);
- for other libraries' conventions: ``flatten_observations=True`` gives each agent a 1-D Box
  (``obs_vehicles_count * 5``,) (RLlib's and BenchMARL's default models take 1-D inputs), and
  ``action_mask_in_observation=True`` PettingZoo's masked-env convention, a Dict observation
  ``{"observation": ..., "action_mask": int8 (5,)}`` that TorchRL's masking reads;
  ``observation_key="observations"`` names the view as RLlib's action-masking RLModule expects.

Unlike :class:`~wrappers.parameter_sharing.ParameterSharingVecEnv`, which feeds AV counts that
vary between copies to one SB3 learner with no padding, a ParallelEnv has a fixed set of possible
agents: one instance per AV count (``n_avs``), as here.
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from sb3_marl.envs import ENV_IDS, MERGE_ENV_IDS, make_scenario
from sb3_marl.envs.config import LANE_CHANGE, MERGE
from sb3_marl.envs.lane_change_env import ACTIONS, LaneChangeEnv
from sb3_marl.envs.reward import REWARD_MODES, apply_reward_mode

#: Per-AV step info copied into each agent's ``infos`` entry.
AGENT_INFO = (
    "speed",
    "headway",
    "crashed",
    "exited",
    "lane_change",
    "proposed_action",
    "executed_action",
    "intervened",
    "rule_action",
)


#: Scenario name -> its ids by density.
SCENARIOS = {LANE_CHANGE: ENV_IDS, MERGE: MERGE_ENV_IDS}


class ScenarioParallelEnv(ParallelEnv):
    """PettingZoo parallel API over one scenario env (see the module doc), named after its scenario
    (``metadata["name"]``: ``sb3_marl_lane_change_v0``, ``sb3_marl_merge_v0``)."""

    metadata = {"name": "sb3_marl_lane_change_v0", "render_modes": ["human", "rgb_array"], "is_parallelizable": True}

    def __init__(
        self,
        density: int = 1,
        reward_mode: str = "local",
        render_mode: str | None = None,
        flatten_observations: bool = False,
        action_mask_in_observation: bool = False,
        observation_key: str = "observation",
        scenario: str = LANE_CHANGE,
        **config: Any,
    ) -> None:
        """
        :param density: traffic density, 1, 2 or 3
        :param reward_mode: ``"local"``, ``"global"`` or ``"individual"``
        :param render_mode: None, ``"rgb_array"`` or ``"human"``
        :param flatten_observations: each agent's observation as a 1-D vector
        :param action_mask_in_observation: each agent's observation as a Dict with its action mask
        :param observation_key: the key of the AV's view in that Dict (PettingZoo's ``observation``;
            ``observations`` for RLlib's ``ActionMaskingTorchRLModule``)
        :param scenario: ``"lane-change"`` or ``"merge"`` (the on-ramp merge)
        :param config: scenario config overrides (``n_avs``, ``safety_supervisor``, ...; see
            :mod:`sb3_marl.envs.config`)
        """
        ids = SCENARIOS.get(scenario)
        if ids is None:
            raise ValueError(f"Invalid scenario={scenario!r}: expected one of {list(SCENARIOS)}.")
        if density not in ids:
            raise ValueError(f"Invalid density={density!r}: expected one of {sorted(ids)}.")
        if reward_mode not in REWARD_MODES:
            raise ValueError(f"Invalid reward_mode={reward_mode!r}: expected one of {list(REWARD_MODES)}.")
        for name, flag in (
            ("flatten_observations", flatten_observations),
            ("action_mask_in_observation", action_mask_in_observation),
        ):
            if not isinstance(flag, bool):
                raise ValueError(f"Invalid {name}={flag!r}: expected True or False.")
        if not isinstance(observation_key, str) or observation_key in ("", "action_mask"):
            raise ValueError(
                f"Invalid observation_key={observation_key!r}: expected a name other than 'action_mask', "
                "e.g. 'observation' (PettingZoo's) or 'observations' (RLlib's)."
            )
        self.metadata = {**self.metadata, "name": f"sb3_marl_{scenario.replace('-', '_')}_v0"}
        self.observation_key = observation_key
        self.flatten_observations = flatten_observations
        self.action_mask_in_observation = action_mask_in_observation
        self.env: LaneChangeEnv = make_scenario(ids[density], config, render_mode)
        self.reward_mode = reward_mode
        self.render_mode = render_mode
        self.possible_agents = [f"av_{i}" for i in range(self.env.n_avs)]
        self.agents: list[str] = []
        per_agent = self.env.observation_space
        low, high = per_agent.low[0], per_agent.high[0]
        if flatten_observations:
            low, high = low.reshape(-1), high.reshape(-1)
        self._observation_space = spaces.Box(low=low, high=high, dtype=per_agent.dtype)  # type: ignore[arg-type]
        self.state_space = spaces.Box(low=-1.0, high=1.0, shape=(int(np.prod(per_agent.shape)),), dtype=per_agent.dtype)  # type: ignore[arg-type]
        self._last_obs: np.ndarray | None = None

    @functools.cache  # noqa: B019  (PettingZoo's convention: the same space object per agent)
    def observation_space(self, agent: str) -> spaces.Space:
        """The AV's kinematic observation: (obs_vehicles_count, 5) in [-1, 1] (flattened with
        ``flatten_observations``; in a Dict beside ``action_mask`` with ``action_mask_in_observation``)."""
        box = spaces.Box(
            low=self._observation_space.low,
            high=self._observation_space.high,
            dtype=self._observation_space.dtype,  # type: ignore[arg-type]
        )
        if not self.action_mask_in_observation:
            return box
        return spaces.Dict({self.observation_key: box, "action_mask": spaces.Box(0, 1, (len(ACTIONS),), dtype=np.int8)})

    @functools.cache  # noqa: B019  (PettingZoo's convention: the same space object per agent)
    def action_space(self, agent: str) -> spaces.Discrete:
        """The 5 meta-actions (:data:`~sb3_marl.envs.lane_change_env.ACTIONS`)."""
        return spaces.Discrete(len(ACTIONS))

    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        obs, info = self.env.reset(seed=seed, options=options)
        self.agents = list(self.possible_agents)
        self._last_obs = obs
        return self._per_agent(obs, info), self._infos(info)

    def step(self, actions: dict[str, int]) -> tuple[dict, dict, dict, dict, dict]:
        if not self.agents:
            raise RuntimeError("The episode is over: call reset() before step().")
        obs, _, terminated, truncated, info = self.env.step(self._action_array(actions))
        self._last_obs = obs
        rewards = apply_reward_mode(info, self.reward_mode)
        result = (
            self._per_agent(obs, info),
            {agent: float(rewards[i]) for i, agent in enumerate(self.possible_agents)},
            {agent: bool(terminated) for agent in self.possible_agents},
            {agent: bool(truncated) for agent in self.possible_agents},
            self._infos(info),
        )
        if terminated or truncated:
            self.agents = []
        return result

    def _action_array(self, actions: Any) -> np.ndarray:
        """One int meta-action per agent from a ``{agent: action}`` dict; a ValueError naming the
        bad agent or action (a float, a string, None, an unknown agent name)."""
        if not isinstance(actions, dict):
            raise ValueError(f"Invalid actions {actions!r}: expected a dict {{agent: meta-action}} for {self.agents}.")
        unknown = sorted(set(actions) - set(self.agents), key=str)
        missing = [agent for agent in self.agents if agent not in actions]
        if unknown or missing:
            raise ValueError(
                f"Invalid actions: unknown agent(s) {unknown}, no action for agent(s) {missing}; "
                f"expected one per agent in {self.agents}."
            )
        for agent, action in actions.items():
            if (
                isinstance(action, (bool, np.bool_))
                or not isinstance(action, (int, np.integer))
                or not 0 <= action < len(ACTIONS)
            ):
                raise ValueError(f"Invalid action {action!r} for {agent}: expected an integer meta-action in {dict(ACTIONS)}.")
        return np.array([int(actions[agent]) for agent in self.possible_agents], dtype=np.int64)

    def state(self) -> np.ndarray:
        """All AVs' observations, flattened: (n_avs * obs_vehicles_count * 5,)."""
        if self._last_obs is None:
            raise RuntimeError("Call reset() before state().")
        return self._last_obs.reshape(-1).copy()

    def render(self) -> np.ndarray | None:
        return self.env.render()

    def close(self) -> None:
        self.env.close()

    def _per_agent(self, obs: np.ndarray, info: dict[str, Any]) -> dict[str, Any]:
        rows = obs.reshape(len(self.possible_agents), -1) if self.flatten_observations else obs
        if not self.action_mask_in_observation:
            return {agent: rows[i] for i, agent in enumerate(self.possible_agents)}
        masks = info["action_mask"].astype(np.int8)
        return {
            agent: {self.observation_key: rows[i], "action_mask": masks[i]} for i, agent in enumerate(self.possible_agents)
        }

    def _infos(self, info: dict[str, Any]) -> dict[str, dict[str, Any]]:
        """Per-agent infos; the action mask here unless it is in the observation (one place, as
        PettingZoo's masked envs: TorchRL reads whichever it finds)."""
        masks = info["action_mask"].astype(np.int8)
        return {
            agent: {
                **({} if self.action_mask_in_observation else {"action_mask": masks[i]}),
                **{key: info[key][i] for key in AGENT_INFO},
            }
            for i, agent in enumerate(self.possible_agents)
        }


def parallel_env(
    density: int = 1, reward_mode: str = "local", render_mode: str | None = None, **kwargs: Any
) -> ScenarioParallelEnv:
    """A scenario (the lane change by default; ``scenario="merge"``: the on-ramp merge) as a
    PettingZoo ``ParallelEnv`` (PettingZoo's constructor name); ``kwargs``: ``scenario``,
    ``flatten_observations``, ``action_mask_in_observation``, ``observation_key`` and scenario
    config keys."""
    return ScenarioParallelEnv(density=density, reward_mode=reward_mode, render_mode=render_mode, **kwargs)


__all__ = ["ScenarioParallelEnv", "parallel_env"]


#: The class's name before 2026-12-04 (it serves the merge too), kept for one release.
LaneChangeParallelEnv = ScenarioParallelEnv
