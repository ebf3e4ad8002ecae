"""ParameterSharingVecEnv: every AV of several scenario copies is one slot of an SB3 VecEnv.

One shared policy then drives all AVs (parameter sharing), trained by any SB3 algorithm.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from functools import partial
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecEnv
from stable_baselines3.common.vec_env.base_vec_env import VecEnvIndices, VecEnvStepReturn

import sb3_marl  # noqa: F401  (registers the scenario ids)
from sb3_marl.envs.config import DENSITIES

REWARD_MODES = ("local", "global", "individual")
VEC_BACKENDS: dict[str, type[VecEnv]] = {"dummy": DummyVecEnv, "subproc": SubprocVecEnv}
#: Copy methods whose result has one row per AV; ``env_method`` hands each slot its own row.
PER_AGENT_METHODS = ("action_masks",)
#: Per-AV arrays of the scenario's info that each slot's info carries as scalars.
PER_AGENT_INFO = ("speed", "headway", "acceleration", "lane_change", "crashed", "exited", "action_mask")

EnvFactory = Callable[[int], gym.Env]


def _make_copy(env: str | EnvFactory, index: int, config: dict[str, Any], render_mode: str | None) -> gym.Env:
    """Copy ``index``: ``env`` called with the index, or ``gymnasium.make(env, config=config)``."""
    if callable(env):
        return env(index)
    return gym.make(env, config=config, render_mode=render_mode)


def _av_count_pattern(env_id: str, config: dict[str, Any]) -> list[int]:
    """AV counts the copies cycle through: the density's AV range, or a fixed ``n_avs``."""
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


class ParameterSharingVecEnv(VecEnv):
    """Flatten the AVs of ``n_copies`` multi-agent scenario copies into one SB3 VecEnv.

    Slot ``j`` of the VecEnv is AV ``i`` of copy ``k`` (copies in order, AVs in order within a
    copy); ``num_envs`` is the total number of AVs. Each slot observes its AV's
    ``(vehicles, features)`` matrix and takes one ``Discrete(5)`` meta-action. With an env id,
    copy k controls the k-th AV count of the density's range, cycling (density 1 with 3 copies:
    1, 2 and 3 AVs), so every slot is always a real AV: no padding, no dummy transitions.

    Rewards per slot by ``reward_mode``: ``local`` (the paper's) is the mean of the per-AV
    rewards over the AV's neighbour set (``info["neighbours"]`` of the copy), ``global`` the mean
    over all AVs of the copy, ``individual`` the AV's own reward.

    When a copy's episode ends, all its slots are done together; each slot's info carries its
    final observation in ``terminal_observation``, ``TimeLimit.truncated`` (True for time-limit
    and road-end truncations, so SB3 bootstraps; crashes are terminations) and
    ``episode = {"r", "l", "t"}`` (the slot's return in the reward mode, length in steps, wall
    time in s), and the copy is reset automatically. Every step's slot info also has the AV's
    driving metrics (speed [m/s], headway [m], acceleration [m/s²], lane_change, crashed,
    exited, action_mask), ``reward`` (its own), ``global_reward``, ``reward_terms`` and
    ``copy`` / ``agent`` indices.

    Each copy runs in an SB3 ``DummyVecEnv`` (``vec_backend="dummy"``, in-process) or
    ``SubprocVecEnv`` (``"subproc"``, one worker process per copy, stepped in parallel); both give
    identical trajectories for the same seed.

    :param env: a scenario id (``sb3_marl/LaneChange-density{1,2,3}-v0``) or a factory
        ``copy_index -> multi-agent env`` following the scenario's contract
    :param n_copies: scenario copies; default: one per AV count of the density's range
    :param reward_mode: ``local``, ``global`` or ``individual``
    :param vec_backend: ``dummy`` or ``subproc``
    :param seed: seed of the first reset (copy k gets ``seed`` + its first slot index)
    :param config: scenario overrides for every copy (with an env id)
    :param render_mode: ``rgb_array`` to render copies (with an env id)
    """

    def __init__(
        self,
        env: str | EnvFactory,
        n_copies: int | None = None,
        reward_mode: str = "local",
        vec_backend: str = "dummy",
        seed: int | None = None,
        config: dict[str, Any] | None = None,
        render_mode: str | None = None,
    ) -> None:
        if reward_mode not in REWARD_MODES:
            raise ValueError(f"Invalid reward_mode={reward_mode!r}: expected one of {list(REWARD_MODES)}.")
        if vec_backend not in VEC_BACKENDS:
            raise ValueError(f"Invalid vec_backend={vec_backend!r}: expected one of {list(VEC_BACKENDS)}.")
        config = dict(config or {})
        pattern = [None] if callable(env) else _av_count_pattern(env, config)
        n_copies = len(pattern) if n_copies is None else n_copies
        if isinstance(n_copies, bool) or not isinstance(n_copies, int) or n_copies < 1:
            raise ValueError(f"Invalid n_copies={n_copies!r}: expected an integer >= 1.")

        self.reward_mode = reward_mode
        self.vec_backend = vec_backend
        factories = []
        for k in range(n_copies):
            copy_config = config if pattern[k % len(pattern)] is None else {**config, "n_avs": pattern[k % len(pattern)]}
            factories.append(partial(_make_copy, env, k, copy_config, render_mode))
        self.copies: list[VecEnv] = [VEC_BACKENDS[vec_backend]([factory]) for factory in factories]
        try:
            single_obs_space, single_action_space, n_avs = self._check_copies()
        except Exception:
            self.close()
            raise
        self.n_avs: list[int] = n_avs
        starts = np.concatenate([[0], np.cumsum(n_avs)])
        self.slices: list[slice] = [slice(int(a), int(b)) for a, b in zip(starts[:-1], starts[1:])]
        self.slot_copy = np.repeat(np.arange(n_copies), n_avs)
        self.slot_agent = np.concatenate([np.arange(n) for n in n_avs])
        super().__init__(int(starts[-1]), single_obs_space, single_action_space)

        self._obs = np.zeros((self.num_envs, *single_obs_space.shape), dtype=single_obs_space.dtype)
        self._episode_returns = np.zeros(self.num_envs)
        self._episode_lengths = np.zeros(self.num_envs, dtype=np.int64)
        self._t_start = time.time()
        self._actions: np.ndarray | None = None
        if seed is not None:
            self.seed(seed)

    def _check_copies(self) -> tuple[spaces.Box, spaces.Discrete, list[int]]:
        """Per-slot spaces and AV counts; a clear error for envs that are not multi-agent scenarios."""
        n_avs, obs_space, action_space = [], None, None
        for k, copy in enumerate(self.copies):
            copy_obs, copy_actions = copy.observation_space, copy.action_space
            if not (
                isinstance(copy_actions, spaces.MultiDiscrete)
                and isinstance(copy_obs, spaces.Box)
                and copy_obs.shape[:1] == copy_actions.shape
                and len(set(copy_actions.nvec.tolist())) == 1
            ):
                raise ValueError(
                    f"Copy {k} is not a multi-agent scenario env: expected a MultiDiscrete action space "
                    f"(one action per AV) and a Box observation space with one row per AV, got "
                    f"{copy_actions} and {copy_obs}."
                )
            agent_obs = spaces.Box(copy_obs.low[0], copy_obs.high[0], dtype=copy_obs.dtype)
            agent_actions = spaces.Discrete(int(copy_actions.nvec[0]))
            if obs_space is not None and (agent_obs != obs_space or agent_actions != action_space):
                raise ValueError(
                    f"Copy {k} has per-AV spaces {agent_obs}, {agent_actions}, unlike copy 0's "
                    f"{obs_space}, {action_space}: all copies must share one per-AV observation and action space."
                )
            obs_space, action_space = agent_obs, agent_actions
            n_avs.append(int(copy_actions.shape[0]))
        return obs_space, action_space, n_avs

    # ---- stepping -------------------------------------------------------------------------

    def reset(self) -> np.ndarray:
        """Reset every copy (with the seeds/options set by ``seed``/``set_options``, if any)."""
        for k, copy in enumerate(self.copies):
            first = self.slices[k].start
            if self._seeds[first] is not None:
                copy.seed(self._seeds[first])
            copy.set_options(self._options[first])
            self._obs[self.slices[k]] = self._call(k, copy.reset)[0]
            info = copy.reset_infos[0]
            self._check_info(k, info)
            for agent, slot in enumerate(range(self.slices[k].start, self.slices[k].stop)):
                self.reset_infos[slot] = self._slot_info(k, agent, info)
        self._episode_returns[:] = 0.0
        self._episode_lengths[:] = 0
        self._reset_seeds()
        self._reset_options()
        return self._obs.copy()

    def step_async(self, actions: np.ndarray) -> None:
        actions = np.asarray(actions)
        if actions.shape not in ((self.num_envs,), (self.num_envs, 1)) or not np.issubdtype(actions.dtype, np.integer):
            raise ValueError(
                f"Invalid actions: expected an int array of shape ({self.num_envs},), one meta-action per AV "
                f"slot, got dtype {actions.dtype} and shape {actions.shape}."
            )
        actions = actions.reshape(self.num_envs)
        bad = np.flatnonzero((actions < 0) | (actions >= self.action_space.n))
        if bad.size:
            raise ValueError(
                f"Invalid actions at slots {bad.tolist()}: {actions[bad].tolist()}, expected integers in "
                f"[0, {self.action_space.n - 1}]."
            )
        for k, copy in enumerate(self.copies):
            self._call(k, copy.step_async, actions[self.slices[k]][None, :])
        self._actions = actions

    def step_wait(self) -> VecEnvStepReturn:
        rewards = np.zeros(self.num_envs, dtype=np.float32)
        dones = np.zeros(self.num_envs, dtype=bool)
        infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        for k, copy in enumerate(self.copies):
            obs, _, done, copy_infos = self._call(k, copy.step_wait)
            info, sl = copy_infos[0], self.slices[k]
            self._obs[sl] = obs[0]
            slot_rewards = self._apply_reward_mode(info)
            rewards[sl] = slot_rewards
            dones[sl] = done[0]
            self._episode_returns[sl] += slot_rewards
            self._episode_lengths[sl] += 1
            for agent, slot in enumerate(range(sl.start, sl.stop)):
                slot_info = self._slot_info(k, agent, info)
                if done[0]:
                    slot_info["terminal_observation"] = info["terminal_observation"][agent]
                    slot_info["TimeLimit.truncated"] = bool(info["TimeLimit.truncated"])
                    slot_info["episode"] = {
                        "r": float(self._episode_returns[slot]),
                        "l": int(self._episode_lengths[slot]),
                        "t": round(time.time() - self._t_start, 6),
                    }
                infos[slot] = slot_info
            if done[0]:
                self._episode_returns[sl] = 0.0
                self._episode_lengths[sl] = 0
                reset_info = copy.reset_infos[0]
                for agent, slot in enumerate(range(sl.start, sl.stop)):
                    self.reset_infos[slot] = self._slot_info(k, agent, reset_info)
        return self._obs.copy(), rewards, dones, infos

    def _apply_reward_mode(self, info: dict[str, Any]) -> np.ndarray:
        """(n_avs,) rewards of one copy's slots in this VecEnv's reward mode."""
        own = np.asarray(info["rewards"], dtype=np.float64)
        if self.reward_mode == "individual":
            return own
        if self.reward_mode == "global":
            return np.full_like(own, own.mean())
        neighbours = np.asarray(info["neighbours"], dtype=np.float64)
        return neighbours @ own / neighbours.sum(axis=1)

    def _slot_info(self, copy: int, agent: int, info: dict[str, Any]) -> dict[str, Any]:
        """One AV's share of its copy's info."""
        own = np.asarray(info["rewards"])
        slot_info = {key: info[key][agent] for key in PER_AGENT_INFO if key in info}
        slot_info.update(
            copy=copy,
            agent=agent,
            reward=float(own[agent]),
            global_reward=float(own.mean()),
            reward_terms={name: float(values[agent]) for name, values in info.get("reward_terms", {}).items()},
        )
        return slot_info

    def _check_info(self, copy: int, info: dict[str, Any]) -> None:
        missing = [key for key in ("rewards", "neighbours") if key not in info]
        if missing:
            raise ValueError(
                f"Copy {copy} is not a multi-agent scenario env: its info lacks {missing} "
                "(per-AV rewards and the local reward's neighbour sets)."
            )

    def _call(self, copy: int, method: Callable, *args: Any) -> Any:
        """Call a copy's VecEnv method; a dead worker becomes an error naming the copy."""
        try:
            return method(*args)
        except (EOFError, BrokenPipeError, ConnectionResetError) as error:
            process = self.copies[copy].processes[0] if self.vec_backend == "subproc" else None
            code = None if process is None else process.exitcode
            raise RuntimeError(
                f"The worker process of scenario copy {copy} (slots {self.slices[copy].start}.."
                f"{self.slices[copy].stop - 1}) died (exit code {code}); see its traceback above."
            ) from error

    # ---- VecEnv plumbing --------------------------------------------------------------------

    def _copies_of(self, indices: VecEnvIndices) -> list[int]:
        """Slot indices -> the copy of each slot."""
        return [int(self.slot_copy[i]) for i in self._get_indices(indices)]

    def _per_copy(self, indices: VecEnvIndices, call: Callable[[VecEnv], Any]) -> dict[int, Any]:
        """Run ``call`` once on each copy owning one of the slots, in copy order."""
        return {k: self._call(k, call, self.copies[k]) for k in sorted(set(self._copies_of(indices)))}

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        """The attribute of each slot's copy."""
        values = self._per_copy(indices, lambda copy: copy.get_attr(attr_name)[0])
        return [values[k] for k in self._copies_of(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        """Set the attribute on the copies owning the slots."""
        self._per_copy(indices, lambda copy: copy.set_attr(attr_name, value))

    def env_method(self, method_name: str, *method_args: Any, indices: VecEnvIndices = None, **method_kwargs: Any) -> list[Any]:
        """Call a method of each slot's copy once per copy; per-AV results (``action_masks``) are split by slot."""
        results = self._per_copy(indices, lambda copy: copy.env_method(method_name, *method_args, **method_kwargs)[0])
        if method_name in PER_AGENT_METHODS:
            return [results[self.slot_copy[i]][self.slot_agent[i]] for i in self._get_indices(indices)]
        return [results[k] for k in self._copies_of(indices)]

    def action_masks(self) -> np.ndarray:
        """(num_envs, 5) bool: available meta-actions of every slot (sb3-contrib's MaskablePPO API)."""
        return np.stack(self.env_method("action_masks"))

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None) -> list[bool]:
        values = self._per_copy(indices, lambda copy: copy.env_is_wrapped(wrapper_class)[0])
        return [values[k] for k in self._copies_of(indices)]

    def get_images(self) -> Sequence[np.ndarray | None]:
        """One frame per scenario copy (a copy shows all its AVs)."""
        return [self._call(k, copy.get_images)[0] for k, copy in enumerate(self.copies)]

    def close(self) -> None:
        for copy in self.copies:
            try:
                copy.close()
            except (EOFError, BrokenPipeError, ConnectionResetError):
                pass  # a dead worker has nothing left to close
