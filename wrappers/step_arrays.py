"""What a :class:`~wrappers.ParameterSharingVecEnv` step tells its learners beyond SB3's return:
typed per-slot arrays (:class:`StepArrays`, one row per slot), read as ``venv.step_arrays``; and
how a copy's episode ended (:class:`Ending`). The step's ``infos`` carry only what SB3, rl_zoo3 and
Monitor read. Units: m, m/s, m/s²."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from sb3_marl.envs.reward import REWARD_MODES, mode_rewards
from sb3_marl.sim.meta_actions import ACTIONS

#: Per-AV arrays of the scenario's step info that :class:`StepArrays` carries, and what a copy
#: that does not report one gets (a factory env following the contract only in part).
PER_AGENT_INFO: dict[str, Any] = {
    "speed": np.nan,
    "headway": np.nan,
    "acceleration": 0.0,
    "lane_change": False,
    "crashed": False,
    "exited": False,
    "action_mask": True,
    "proposed_action": -1,
    "executed_action": -1,
    "intervened": False,
    "rule_action": -1,
}


@dataclass(frozen=True)
class StepArrays:
    """One step's per-slot arrays, slot j at row j (copy by copy, AVs in order), all of the
    step's new state, i.e. of the terminal state where a copy's episode ended; after a reset, of
    the first observations (``proposed_action`` and ``executed_action`` -1)."""

    speed: np.ndarray  #: [m/s]
    headway: np.ndarray  #: [m] to the leader in the AV's lane
    acceleration: np.ndarray  #: [m/s²] over the step
    lane_change: np.ndarray  #: bool, the AV changed lane in the step
    crashed: np.ndarray  #: bool
    exited: np.ndarray  #: bool, the AV has passed the road's end
    action_mask: np.ndarray  #: (slots, 5) bool, the available meta-actions of the new observation
    proposed_action: np.ndarray  #: int, the policy's meta-action
    executed_action: np.ndarray  #: int, the one the safety supervisor let through
    intervened: np.ndarray  #: bool, the supervisor replaced the proposal or braked (shadow: would have)
    rule_action: np.ndarray  #: int, the rule driver's meta-action in the new state
    reward: np.ndarray  #: the AV's own reward (before the reward mode)
    global_reward: np.ndarray  #: the mean reward of the AV's copy
    reward_terms: dict[str, np.ndarray]  #: each unweighted reward term
    copy: np.ndarray  #: int, the slot's scenario copy
    agent: np.ndarray  #: int, the slot's AV within its copy

    @classmethod
    def join(cls, parts: Sequence[dict[str, Any]], copy: np.ndarray, agent: np.ndarray) -> StepArrays:
        """The arrays of several copies' :func:`copy_arrays`, copy after copy (reward terms: those
        every copy reports)."""
        if len(parts) == 1:  # the batched step's arrays, one row per slot already
            part = parts[0]
            values = {key: part[key] for key in (*PER_AGENT_INFO, "reward", "global_reward")}
            return cls(**values, reward_terms=dict(part["reward_terms"]), copy=copy, agent=agent)
        joined = {key: np.concatenate([part[key] for part in parts]) for key in (*PER_AGENT_INFO, "reward", "global_reward")}
        terms = [part["reward_terms"] for part in parts]
        shared = [name for name in terms[0] if all(name in t for t in terms)]
        reward_terms = {name: np.concatenate([t[name] for t in terms]) for name in shared}
        return cls(**joined, reward_terms=reward_terms, copy=copy, agent=agent)


def current_action_masks(venv: Any) -> np.ndarray:
    """(num_envs, actions) bool: every slot's action mask for the current observations, from the
    parameter-sharing VecEnv under ``venv``'s wrappers (or any VecEnv's ``action_masks`` per env)."""
    if hasattr(venv, "action_masks"):
        return np.asarray(venv.action_masks(), dtype=bool)
    return np.stack(venv.env_method("action_masks")).astype(bool)


def current_rule_actions(venv: Any) -> np.ndarray:
    """(num_envs,) int: the rule driver's action for every slot's current observation."""
    if hasattr(venv, "rule_actions"):
        return np.asarray(venv.rule_actions(), dtype=np.int64)
    return np.asarray(venv.env_method("rule_actions"), dtype=np.int64)


def stack_observations(observations: list[Any]) -> Any:
    """Slots' observations (arrays, or dicts of arrays) as one batch."""
    if isinstance(observations[0], dict):
        return {key: np.stack([obs[key] for obs in observations]) for key in observations[0]}
    return np.stack(observations)


def step_arrays_of(venv: Any) -> StepArrays | None:
    """The last step's arrays of the parameter-sharing VecEnv under ``venv``'s VecEnvWrappers
    (None: another kind of VecEnv)."""
    return getattr(venv, "step_arrays", None)


def copy_arrays(info: dict[str, Any]) -> dict[str, Any]:
    """One copy's share of :class:`StepArrays` from its scenario info: the entries of
    :data:`PER_AGENT_INFO` (a default where the info has none), ``reward`` (the AV's own),
    ``global_reward`` (the copy's mean) and ``reward_terms`` (a dict of arrays)."""
    own = np.asarray(info["rewards"], dtype=np.float64)
    arrays: dict[str, Any] = {}
    for key, default in PER_AGENT_INFO.items():
        shape = (own.size, len(ACTIONS)) if key == "action_mask" else own.size
        arrays[key] = np.asarray(info[key]) if key in info else np.full(shape, default)
    arrays["reward"] = own
    arrays["global_reward"] = mode_rewards(own, np.ones((own.size, own.size), dtype=np.bool_), REWARD_MODES.index("global"))
    arrays["reward_terms"] = {name: np.asarray(values) for name, values in info.get("reward_terms", {}).items()}
    return arrays


class Endings(NamedTuple):
    """Which copies' episodes ended in a VecEnv step and how: over the copies, whether it ended and
    whether by a time limit or the road's end (SB3's ``TimeLimit.truncated``; a crash is a
    termination); over the AV slots, the ended episodes' last observations (rows of copies that
    went on: anything), and the action masks and rule actions of the observations the next step
    starts from (the new episodes' first where one ended)."""

    ended: np.ndarray  # (copies,) bool
    time_limit: np.ndarray  # (copies,) bool
    terminal_observation: np.ndarray  # (slots, vehicles, features)
    action_mask: np.ndarray  # (slots, 5) bool
    rule_action: np.ndarray  # (slots,) int


class Ending(NamedTuple):
    """How a copy's episode ended: its last observations (n_avs, ...), whether by a time limit or
    the road's end (SB3's ``TimeLimit.truncated``; a crash is a termination), and the arrays of the
    new episode's first observations (:func:`copy_arrays`)."""

    terminal_observation: np.ndarray
    time_limit: bool
    reset_arrays: dict[str, Any]
