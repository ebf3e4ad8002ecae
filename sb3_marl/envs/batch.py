"""Every copy of a scenario stepped in one compiled call (:class:`RoadBatch`).

The copies' states lie in one array and one call of
:func:`~sb3_marl.envs.batch_kernel.step_copies` steps them all (the supervisor, the frames of the
step, observations, rewards, neighbour sets, masks, the rule driver's actions): the step a single
scenario env takes as a batch of one, so the same seeds give the same episodes (tests/envs/test_batch.py
compares them step by step). The scenario envs stay the copies' owners:
they spawn every episode (their seeded generators, once per finished episode), and get their state
back when asked (:meth:`RoadBatch.sync`). Units: m, m/s, m/s², s, Hz.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sb3_marl.envs.batch_kernel import BatchStep, copy_rewards, observe_copies, step_copies, step_report
from sb3_marl.envs.lane_change_env import LaneChangeEnv
from sb3_marl.envs.merge_env import MergeEnv
from sb3_marl.envs.merge_rules import ON_RAMP_SIDE
from sb3_marl.envs.reward import REWARD_MODES
from sb3_marl.sim import kernel

#: The global reward mode's index (each slot's copy's mean reward).
GLOBAL = REWARD_MODES.index("global")
#: Config keys that may differ between the copies of one batch (or between episodes of a copy).
PER_COPY_KEYS = ("n_avs", "safety_supervisor", "supervisor_shadow")


class RoadBatch:
    """The copies of one scenario config (lane change or merge; they may differ only in
    :data:`PER_COPY_KEYS`) stepped together; copy k's env spawns its episodes, and :meth:`load`
    takes its state after each reset. On the merge it also keeps which AVs started on the ramp and
    when they reached the main road (the env's ``ramp_av`` and ``merge_time``).

    :param envs: the copies' unwrapped scenario envs, each reset
    :param reward_mode: ``local``, ``global`` or ``individual`` (:data:`~sb3_marl.envs.reward.REWARD_MODES`)
    """

    def __init__(self, envs: list[LaneChangeEnv], reward_mode: str) -> None:
        self.envs = envs
        self.mode = REWARD_MODES.index(reward_mode)
        self._shared = _shared_config(envs[0])
        self.parameters = envs[0].step_parameters()
        self.n_avs = np.array([env.n_avs for env in envs], dtype=np.int64)
        self.slot_starts = np.concatenate([[0], np.cumsum(self.n_avs)]).astype(np.int64)
        self.states = np.zeros((0, kernel.COLUMNS))  # every copy's rows, added by load() below
        self.offsets = np.zeros(len(envs) + 1, dtype=np.int64)
        self.steps = np.zeros(len(envs), dtype=np.int64)
        self.supervise, self.shadow = np.zeros(len(envs), dtype=np.bool_), np.zeros(len(envs), dtype=np.bool_)
        self._stale = False  # whether the envs' states are behind the batch's
        self.ramp_av = np.zeros(int(self.slot_starts[-1]), dtype=np.bool_)
        self.merge_time = np.full(int(self.slot_starts[-1]), np.nan)  # [s]
        for k in range(len(envs)):
            self.load(k)

    def load(self, k: int, check: bool = True) -> None:
        """Take copy k's state from its env (after a reset); ``check``: that its config is still the
        batch's (a reset's options may change it; the per-episode supervisor dropout changes only
        :data:`PER_COPY_KEYS`)."""
        env = self.envs[k]
        if check and (_shared_config(env) != self._shared or env.n_avs != self.n_avs[k]):
            raise RuntimeError(
                f"Scenario copy {k}'s config changed beyond {list(PER_COPY_KEYS)}: a batch steps copies of one "
                "config (use batched=False to step the copies one by one)."
            )
        a, b = self.offsets[k], self.offsets[k + 1]
        self.states = np.concatenate([self.states[:a], env.state, self.states[b:]])
        self.offsets[k + 1 :] += len(env.state) - (b - a)
        self.steps[k] = env.steps_done
        self.supervise[k] = bool(env.config["safety_supervisor"])
        self.shadow[k] = bool(env.config["supervisor_shadow"])
        if self.parameters.merge:  # a new situation: as MergeEnv._scenario_info at step 0
            sl = slice(self.slot_starts[k], self.slot_starts[k + 1])
            self.ramp_av[sl] = ON_RAMP_SIDE[env.state[: env.n_avs, kernel.LANE].astype(np.int64)]
            self.merge_time[sl] = np.nan

    def step(self, actions: np.ndarray) -> tuple[BatchStep, dict[str, Any], np.ndarray]:
        """Step every copy with one meta-action per slot (int array (slots,)): the step, the slot
        infos' arrays (:meth:`slot_arrays`) and every slot's reward in the reward mode."""
        actions = np.asarray(actions, dtype=np.int64)
        result = step_copies(
            self.states, self.offsets, self.slot_starts, actions, self.supervise, self.shadow, self.steps, self.parameters
        )
        self.states, self.offsets, self._stale = result.states[: result.offsets[-1]], result.offsets, True
        if self.parameters.merge:
            merged = self.ramp_av & np.isnan(self.merge_time) & ~ON_RAMP_SIDE[result.lane]
            steps = np.repeat(self.steps, self.n_avs)
            self.merge_time[merged] = steps[merged] / self.envs[0].config["policy_frequency"]
        arrays = self.slot_arrays(result, actions)
        return result, arrays, copy_rewards(arrays["reward"], result.neighbours, self.slot_starts, self.mode)

    def start(self, copies: np.ndarray) -> tuple[BatchStep, dict[str, Any]]:
        """The first observations of the new episodes of ``copies`` (each :meth:`load`-ed) and
        their per-slot arrays; the other slots are empty."""
        slots = int(self.slot_starts[-1])
        still, straight = np.zeros(slots), np.zeros(slots, dtype=np.bool_)  # a first observation: no motion yet
        copies = np.asarray(copies, dtype=np.int64)
        result = observe_copies(self.states, self.offsets, self.slot_starts, copies, still, straight, self.parameters)
        return result, self.slot_arrays(result, result.executed)

    def slot_arrays(self, result: BatchStep, proposed: np.ndarray) -> dict[str, Any]:
        """The per-slot arrays of a step (:func:`~sb3_marl.envs.batch_kernel.step_report`) with
        each AV's copy's mean reward (``global_reward``)."""
        arrays = step_report(result, proposed, self.envs[0].config, self.parameters.merge)
        arrays["global_reward"] = copy_rewards(arrays["reward"], result.neighbours, self.slot_starts, GLOBAL)
        return arrays

    def sync(self) -> None:
        """Give every copy's env its current state (before anything reads the envs)."""
        if not self._stale:
            return
        frames = self.parameters.horizon.frames_per_step
        for k, env in enumerate(self.envs):
            for _ in range(int(self.steps[k]) - env.steps_done):
                env.time += 1.0 / env.config["policy_frequency"]  # as the env's own steps add it up
            env.state = self.states[self.offsets[k] : self.offsets[k + 1]].copy()
            env.steps, env.done = int(self.steps[k]) * frames, False
            if self.parameters.merge:
                sl = slice(self.slot_starts[k], self.slot_starts[k + 1])
                env._ramp_avs, env._merge_time = self.ramp_av[sl].copy(), self.merge_time[sl].copy()
        self._stale = False


def _shared_config(env: LaneChangeEnv) -> dict[str, Any]:
    return {key: value for key, value in env.config.items() if key not in PER_COPY_KEYS}


def batchable(env: Any) -> bool:
    """Whether a copy can be stepped in a :class:`RoadBatch`: the lane change or the merge itself,
    compiled, drawing no frames."""
    return type(env) in (LaneChangeEnv, MergeEnv) and not env._uses_objects()
