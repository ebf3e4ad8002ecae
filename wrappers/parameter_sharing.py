"""ParameterSharingVecEnv: every AV of several scenario copies is one slot of an SB3 VecEnv.

One shared policy then drives all AVs (parameter sharing), trained by any SB3 algorithm.
"""

from __future__ import annotations

import itertools
import os
import time
from collections.abc import Callable, Sequence
from functools import partial
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env import VecEnv
from stable_baselines3.common.vec_env.base_vec_env import (
    VecEnvIndices,
    VecEnvStepReturn,
)

from sb3_marl.common.checks import check_choice, check_integer, check_number
from sb3_marl.envs import (  # importing sb3_marl.envs registers the scenario ids
    av_counts,
    copy_av_counts,
)
from sb3_marl.envs.batch import RoadBatch, batchable
from sb3_marl.envs.reward import REWARD_MODES
from wrappers.copies import CopyGroups, CopyRunner, per_agent_spaces, run_calls
from wrappers.step_arrays import Endings, StepArrays

VEC_BACKENDS = ("dummy", "subproc")
#: Copy methods whose result has one row per AV; ``env_method`` hands each slot its own row.
PER_AGENT_METHODS = ("action_masks", "rule_actions")
#: Per-AV methods answered from the current observations' arrays: method -> :class:`StepArrays` field.
CACHED_METHODS = {"action_masks": "action_mask", "rule_actions": "rule_action"}
EnvFactory = Callable[[int], gym.Env]
#: Calls sent to the copies: their results already (``dummy``), or the worker groups that will answer (``subproc``).
Pending = dict[int, Any] | list[tuple[int, list[int]]]


def check_sharing_options(reward_mode: str, n_copies: int | None) -> None:
    """``reward_mode`` and ``n_copies`` (None: one copy per AV count): a ValueError naming the bad one."""
    check_choice("reward_mode", reward_mode, list(REWARD_MODES))
    if n_copies is not None:
        check_integer("n_copies", n_copies, 1, expected="an integer >= 1 (or None: one per AV count)")


def check_supervisor_dropout(dropout: float) -> None:
    """A ValueError naming ``supervisor_dropout`` unless it is a probability in [0, 1]."""
    check_number("supervisor_dropout", dropout, 0, 1, expected="a probability in [0, 1] (0: off)")


def _make_copy(env: str | EnvFactory, index: int, config: dict[str, Any], render_mode: str | None) -> gym.Env:
    """Copy ``index``: ``env`` called with the index, or ``gymnasium.make(env, config=config)``."""
    if callable(env):
        return env(index)
    return gym.make(env, config=config, render_mode=render_mode)


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
    time in s), and the copy is reset automatically; the other infos are empty. What else the step
    did, per slot, is in :attr:`step_arrays` (:class:`~wrappers.step_arrays.StepArrays`: driving
    metrics, masks, proposed and executed actions, interventions, rule actions, rewards and their
    terms, copy and AV indices), which learners and callbacks read (through any VecEnvWrapper).

    ``vec_backend="dummy"`` steps the copies in this process; ``"subproc"`` spreads them
    round-robin over ``n_workers`` worker processes (default: one per CPU core, at most one per
    copy) that step in parallel. Both give identical trajectories for the same seed.

    :param env: a scenario id (``sb3_marl/LaneChange-density{1,2,3}-v0``) or a factory
        ``copy_index -> multi-agent env`` following the scenario's contract
    :param n_copies: scenario copies; default: one per AV count of the density's range
    :param reward_mode: ``local``, ``global`` or ``individual``
    :param vec_backend: ``dummy`` or ``subproc``
    :param seed: seed of the first reset (copy k gets ``seed`` + its first slot index)
    :param config: scenario overrides for every copy (with an env id)
    :param render_mode: ``rgb_array`` to render copies (with an env id)
    :param n_workers: worker processes of the ``subproc`` backend
    :param start_method: multiprocessing start method of the workers (default: ``forkserver``
        where available, as SB3's ``SubprocVecEnv``)
    :param worker_timeout: seconds a ``subproc`` worker may take to answer one call before the
        call fails with a ``TimeoutError`` naming its copies (a stopped worker never blocks)
    :param supervisor_dropout: probability in [0, 1] that a training episode of a copy runs without
        the scenario's safety supervisor (see :class:`CopyRunner`; 0: always as configured)
    :param batched: step the copies of a scenario id (lane change or merge) in one compiled call
        (:class:`~sb3_marl.envs.batch.RoadBatch`; ``dummy`` backend, no rendering; the same
        episodes as stepping them one by one, which ``False`` does, and the other cases)
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
        n_workers: int | None = None,
        start_method: str | None = None,
        worker_timeout: float = 120.0,
        supervisor_dropout: float = 0.0,
        batched: bool = True,
    ) -> None:
        check_sharing_options(reward_mode, n_copies)
        check_supervisor_dropout(supervisor_dropout)
        if vec_backend not in VEC_BACKENDS:
            raise ValueError(f"Invalid vec_backend={vec_backend!r}: expected one of {list(VEC_BACKENDS)}.")
        config = dict(config or {})
        n_copies = (1 if callable(env) else len(av_counts(env, config))) if n_copies is None else n_copies
        copy_counts = [None] * n_copies if callable(env) else copy_av_counts(env, config, n_copies)
        if vec_backend == "dummy":
            n_workers = None  # in this process
        elif n_workers is None:
            n_workers = min(n_copies, os.cpu_count() or 1)
        else:
            check_integer("n_workers", n_workers, 1, n_copies, expected=f"an integer in [1, n_copies={n_copies}]")

        self.reward_mode = reward_mode
        self.vec_backend = vec_backend
        runners = []
        for k, count in enumerate(copy_counts):
            copy_config = config if count is None else {**config, "n_avs": count}
            runners.append(
                partial(
                    CopyRunner,
                    partial(_make_copy, env, k, copy_config, render_mode),
                    k,
                    reward_mode,
                    float(supervisor_dropout),
                )
            )
        #: the copies' runners on the ``dummy`` backend, called directly; on ``subproc``, their worker processes
        self.runners: list[CopyRunner] = [make_runner() for make_runner in runners] if n_workers is None else []
        self.copies = None if n_workers is None else CopyGroups(runners, n_workers, start_method, worker_timeout)
        try:
            copy_spaces = self._run(dict.fromkeys(range(n_copies), ("spaces", ())))
            single_obs_space, single_action_space, n_avs = per_agent_spaces(copy_spaces)
        except Exception:
            self.close()
            raise
        self.n_avs: list[int] = n_avs
        self._copy_avs = np.array(n_avs)
        envs = [runner.env.unwrapped for runner in self.runners]
        use_batch = batched and isinstance(env, str) and render_mode is None and envs and all(map(batchable, envs))
        self.batch = RoadBatch(envs, reward_mode) if use_batch else None  # type: ignore[arg-type]
        starts = np.concatenate([[0], np.cumsum(n_avs)])
        self.slices: list[slice] = [slice(int(a), int(b)) for a, b in itertools.pairwise(starts)]
        self.slot_copy = np.repeat(np.arange(n_copies), n_avs)
        self.slot_agent = np.concatenate([np.arange(n) for n in n_avs])
        super().__init__(int(starts[-1]), single_obs_space, single_action_space)

        self._obs = np.zeros((self.num_envs, *single_obs_space.shape), dtype=single_obs_space.dtype)
        #: the last step's (or reset's) per-slot arrays
        self.step_arrays: StepArrays | None = None
        #: action masks and rule actions of the current observations (an ended copy's: its new episode's)
        self._current: dict[str, np.ndarray] = {}
        self._episode_returns = np.zeros(self.num_envs)
        self._episode_lengths = np.zeros(self.num_envs, dtype=np.int64)
        self._t_start = time.time()
        if seed is not None:
            self.seed(seed)

    @property
    def n_copies(self) -> int:
        return len(self.runners) if self.copies is None else len(self.copies.placement)

    # ---- running calls on copies -----------------------------------------------------------

    def _submit(self, calls: dict[int, tuple[str, tuple]]) -> Pending:
        """Send ``{copy: (CopyRunner method, args)}`` to the copies (on the ``dummy`` backend: run
        them now); returns what :meth:`_collect` needs."""
        self._check_open()
        if self.copies is None:
            return dict(zip(calls, run_calls(self.runners, [(k, *call) for k, call in calls.items()])))
        return self.copies.submit(calls)

    def _check_open(self) -> None:
        if getattr(self, "closed", False):
            raise RuntimeError("This ParameterSharingVecEnv is closed: create a new one.")

    def _collect(self, pending: Pending) -> dict[int, Any]:
        """``{copy: result}`` of the calls :meth:`_submit` sent."""
        if isinstance(pending, dict):
            results = pending
        else:
            assert self.copies is not None, "worker groups answer the subproc backend's calls"
            results = self.copies.collect(pending)
        batch = getattr(self, "batch", None)
        if batch is not None:
            batch.check()  # the call may have reconfigured a copy
        return results

    def _run(self, calls: dict[int, tuple[str, tuple]]) -> dict[int, Any]:
        """Run ``{copy: (CopyRunner method, args)}``, all groups in parallel; ``{copy: result}``."""
        return self._collect(self._submit(calls))

    # ---- stepping -------------------------------------------------------------------------

    def reset(self) -> np.ndarray:
        """Reset every copy (with the seeds/options set by ``seed``/``set_options``, if any)."""
        calls = {k: ("reset", (self._seeds[sl.start], self._options[sl.start])) for k, sl in enumerate(self.slices)}
        results = self._run(calls)
        for k, (obs, _) in results.items():
            self._obs[self.slices[k]] = obs
        self.step_arrays = self._join([results[k][1] for k in range(self.n_copies)])
        self.reset_infos = [{} for _ in range(self.num_envs)]
        self._current = {method: getattr(self.step_arrays, key).copy() for method, key in CACHED_METHODS.items()}
        self._episode_returns[:] = 0.0
        self._episode_lengths[:] = 0
        self._reset_seeds()
        self._reset_options()
        return self._obs.copy()

    def step_async(self, actions: np.ndarray) -> None:
        actions = np.asarray(actions)
        if actions.shape not in ((self.num_envs,), (self.num_envs, 1)) or actions.dtype.kind not in "iu":
            raise ValueError(
                f"Invalid actions: expected an int array of shape ({self.num_envs},), one meta-action per AV "
                f"slot, got dtype {actions.dtype} and shape {actions.shape}."
            )
        actions = actions.reshape(self.num_envs)
        n_actions = int(self.action_space.n)  # type: ignore[attr-defined]
        if actions.min() < 0 or actions.max() >= n_actions:
            bad = np.flatnonzero((actions < 0) | (actions >= n_actions))
            raise ValueError(
                f"Invalid actions at slots {bad.tolist()}: {actions[bad].tolist()}, expected integers in [0, {n_actions - 1}]."
            )
        if self.batch is not None:
            self._check_open()
            self._actions = actions.astype(np.int64)
        else:
            self._pending = self._submit({k: ("step", (actions[sl],)) for k, sl in enumerate(self.slices)})

    def step_wait(self) -> VecEnvStepReturn:
        if self.batch is not None:
            return self._step_batch()
        results = self._collect(self._pending)
        rewards = np.zeros(self.num_envs)
        arrays = self._join([results[k][3] for k in range(self.n_copies)])
        ended, time_limit = np.zeros(self.n_copies, dtype=bool), np.zeros(self.n_copies, dtype=bool)
        terminal, mask, rule = self._obs.copy(), arrays.action_mask.copy(), arrays.rule_action.copy()
        for k, (obs, slot_rewards, _, _, ending) in results.items():
            sl = self.slices[k]
            self._obs[sl], rewards[sl] = obs, slot_rewards
            if ending is not None:
                ended[k], time_limit[k], terminal[sl] = True, ending.time_limit, ending.terminal_observation
                mask[sl], rule[sl] = ending.reset_arrays["action_mask"], ending.reset_arrays["rule_action"]
        return self._finish(rewards, arrays, Endings(ended, time_limit, terminal, mask, rule))

    def _step_batch(self) -> VecEnvStepReturn:
        """One compiled step of every copy (:class:`~sb3_marl.envs.batch.RoadBatch`), which begins
        a new episode wherever one ended (as the copy's env would draw it) in the same call."""
        assert self.batch is not None
        step, starts, arrays, rewards = self.batch.step(self._actions)
        self._obs[:] = starts.obs
        endings = Endings(starts.restarted, step.truncated, step.obs, starts.action_mask, starts.rule_action)
        return self._finish(rewards, StepArrays.join([arrays], self.slot_copy, self.slot_agent), endings)

    def _join(self, parts: list[dict[str, Any]]) -> StepArrays:
        """The copies' per-AV arrays (:func:`~wrappers.step_arrays.copy_arrays`) over the slots."""
        return StepArrays.join(parts, self.slot_copy, self.slot_agent)

    def _finish(self, rewards: np.ndarray, arrays: StepArrays, endings: Endings) -> VecEnvStepReturn:
        """The step's return from every slot's reward, the step's arrays and how the copies whose
        episode ended ended (their observations in ``self._obs`` already the new episode's)."""
        self._episode_returns += rewards
        self._episode_lengths += 1
        self.step_arrays = arrays
        infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        dones = np.repeat(endings.ended, self._copy_avs)
        self._current = {method: getattr(endings, key) for method, key in CACHED_METHODS.items()}
        if dones.any():
            elapsed = round(time.time() - self._t_start, 6)
            slots = np.flatnonzero(dones)
            time_limit = endings.time_limit[self.slot_copy[slots]].tolist()
            returns, lengths = self._episode_returns[slots].tolist(), self._episode_lengths[slots].tolist()
            terminal = list(endings.terminal_observation[slots])
            for slot, obs, truncated, r, length in zip(slots.tolist(), terminal, time_limit, returns, lengths):
                infos[slot] = {
                    "terminal_observation": obs,
                    "TimeLimit.truncated": truncated,
                    "episode": {"r": r, "l": length, "t": elapsed},
                }
            self._episode_returns[dones] = 0.0
            self._episode_lengths[dones] = 0
        return self._obs.copy(), rewards.astype(np.float32), dones, infos

    # ---- VecEnv plumbing --------------------------------------------------------------------

    def _copies_of(self, indices: VecEnvIndices) -> list[int]:
        """Slot indices -> the copy of each slot."""
        return [int(self.slot_copy[i]) for i in self._get_indices(indices)]

    def _per_copy(self, indices: VecEnvIndices, method: str, *args: Any) -> dict[int, Any]:
        """Run a CopyRunner method once on each copy owning one of the slots."""
        return self._run(dict.fromkeys(set(self._copies_of(indices)), (method, args)))

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        """The attribute of each slot's copy."""
        values = self._per_copy(indices, "get_attr", attr_name)
        return [values[k] for k in self._copies_of(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        """Set the attribute on the copies owning the slots."""
        self._per_copy(indices, "set_attr", attr_name, value)

    def has_attr(self, attr_name: str) -> bool:
        if attr_name in CACHED_METHODS:
            return True  # the scenario's, through :meth:`action_masks` / :meth:`rule_actions`
        return super().has_attr(attr_name)

    def env_method(
        self, method_name: str, *method_args: Any, indices: VecEnvIndices = None, **method_kwargs: Any
    ) -> list[Any]:
        """Call a method of each slot's copy once per copy; per-AV results (``action_masks``,
        ``rule_actions``) are split by slot.

        ``action_masks`` and ``rule_actions`` are answered from what the copies reported with the
        current observations (no call to the copies: learners ask for them on every step)."""
        self._check_open()
        if method_name in self._current and not method_args and not method_kwargs:
            return list(self._current[method_name][list(self._get_indices(indices))])
        results = self._per_copy(indices, "env_method", method_name, method_args, method_kwargs)
        if method_name in PER_AGENT_METHODS:
            return [results[self.slot_copy[i]][self.slot_agent[i]] for i in self._get_indices(indices)]
        return [results[k] for k in self._copies_of(indices)]

    def action_masks(self) -> np.ndarray:
        """(num_envs, 5) bool: available meta-actions of every slot (sb3-contrib's MaskablePPO API)."""
        return self._current_rows("action_masks").copy()

    def rule_actions(self) -> np.ndarray:
        """(num_envs,) int: the rule driver's meta-action for every slot's current observation."""
        return self._current_rows("rule_actions").astype(np.int64)

    def _current_rows(self, method: str) -> np.ndarray:
        """Every slot's row of a per-AV method (:data:`CACHED_METHODS`) for the current observations."""
        self._check_open()
        if method not in self._current:
            raise RuntimeError(f"{method}() needs the copies' current observations: call reset() first.")
        return self._current[method]

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None) -> list[bool]:
        values = self._per_copy(indices, "env_is_wrapped", wrapper_class)
        return [values[k] for k in self._copies_of(indices)]

    def get_images(self) -> Sequence[np.ndarray | None]:
        """One frame per scenario copy (a copy shows all its AVs)."""
        images = self._run(dict.fromkeys(range(self.n_copies), ("get_image", ())))
        return [images[k] for k in range(self.n_copies)]

    def copy_env(self, copy: int) -> gym.Env:
        """The unwrapped scenario env of a copy (``dummy`` backend only: workers keep theirs)."""
        if self.vec_backend != "dummy":
            raise RuntimeError("copy_env() needs vec_backend='dummy': subproc copies live in worker processes.")
        return self.runners[copy].env.unwrapped

    def close(self) -> None:
        self.closed = True
        for runner in getattr(self, "runners", []):
            runner.close()
        copies: CopyGroups | None = getattr(self, "copies", None)
        if copies is not None:
            copies.close()
