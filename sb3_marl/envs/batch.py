"""Every copy of a scenario stepped in one compiled call (:class:`RoadBatch`).

The copies' states lie in one array and one call of
:func:`~sb3_marl.envs.batch_kernel.step_copies` steps them all (the supervisor, the frames of the
step, observations, rewards, neighbour sets, masks, the rule driver's actions) and begins a new
episode where one ended: the step a single scenario env takes as a batch of one, and the spawn its
reset draws, from the env's own generator state (:mod:`~sb3_marl.sim.pcg64`), so the same seeds
give the same episodes (tests/envs/test_batch.py compares them step by step). The scenario envs
spawn the episodes of a seeded reset; :meth:`RoadBatch.load` takes a copy's state (and its
generators') from its env, :meth:`RoadBatch.sync` gives it back when something reads the env.
Units: m, m/s, m/s², s, Hz.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sb3_marl.envs.batch_kernel import BatchStep, CopyState, Starts, copy_rewards, step_copies, step_report
from sb3_marl.envs.config import with_supervisor
from sb3_marl.envs.lane_change_env import LaneChangeEnv
from sb3_marl.envs.merge_env import MergeEnv
from sb3_marl.envs.merge_rules import ON_RAMP_SIDE
from sb3_marl.envs.reward import REWARD_MODES
from sb3_marl.sim import kernel, pcg64

#: The global reward mode's index (each slot's copy's mean reward).
GLOBAL = REWARD_MODES.index("global")
#: Config keys that may differ between the copies of one batch (or between episodes of a copy).
PER_COPY_KEYS = ("n_avs", "safety_supervisor", "supervisor_shadow")


class RoadBatch:
    """The copies of one scenario config (lane change or merge; they may differ only in
    :data:`PER_COPY_KEYS`) stepped together, each new episode begun inside the step; :meth:`load`
    takes a copy's state from its env after the env's own reset. On the merge it also keeps which
    AVs started on the ramp and when they reached the main road (the env's ``ramp_av`` and
    ``merge_time``).

    :param envs: the copies' unwrapped scenario envs, each reset
    :param reward_mode: ``local``, ``global`` or ``individual`` (:data:`~sb3_marl.envs.reward.REWARD_MODES`)
    """

    def __init__(self, envs: list[LaneChangeEnv], reward_mode: str) -> None:
        self.envs = envs
        self.mode = REWARD_MODES.index(reward_mode)
        self._shared = _shared_config(envs[0])
        self.parameters = envs[0].step_parameters()
        n = len(envs)
        self.n_avs = np.array([env.n_avs for env in envs], dtype=np.int64)
        self.slot_starts = np.concatenate([[0], np.cumsum(self.n_avs)]).astype(np.int64)
        self.states = np.zeros((0, kernel.COLUMNS))  # every copy's rows, added by load() below
        self.offsets = np.zeros(n + 1, dtype=np.int64)
        words = np.zeros((n, 6), dtype=np.uint64)
        zeros = np.zeros(n, dtype=np.int64)
        self.copies = CopyState(zeros, zeros > 0, zeros > 0, zeros.copy(), words, words.copy(), np.zeros(n))
        self._dropout_generators: list[np.random.Generator | None] = [None] * n
        self._stale = False  # whether the envs' states are behind the batch's
        self._restarted = np.zeros(n, dtype=np.bool_)  # a new episode since the envs last had their state
        self.ramp_av = np.zeros(int(self.slot_starts[-1]), dtype=np.bool_)
        self.merge_time = np.full(int(self.slot_starts[-1]), np.nan)  # [s]
        for k in range(n):
            self.load(k)

    def load(self, k: int, dropout_generator: np.random.Generator | None = None, dropout: float = 0.0) -> None:
        """Take copy k's state from its env (after a reset, or after anything changed the env) and
        that its config is still the batch's (a reset's options may change it; the per-episode
        supervisor dropout changes only :data:`PER_COPY_KEYS`); with a ``dropout`` p > 0, each new
        episode the batch begins draws from ``dropout_generator`` whether it runs the supervisor
        (off with probability p)."""
        env = self.envs[k]
        if _shared_config(env) != self._shared or env.n_avs != self.n_avs[k]:
            raise RuntimeError(
                f"Scenario copy {k}'s config changed beyond {list(PER_COPY_KEYS)}: a batch steps copies of one "
                "config (use batched=False to step the copies one by one)."
            )
        a, b = self.offsets[k], self.offsets[k + 1]
        self.states = np.concatenate([self.states[:a], env.state, self.states[b:]])
        self.offsets[k + 1 :] += len(env.state) - (b - a)
        c = self.copies
        c.steps[k], c.n_hdvs[k] = env.steps_done, env.n_hdvs
        c.supervise[k], c.shadow[k] = bool(env.config["safety_supervisor"]), bool(env.config["supervisor_shadow"])
        c.generators[k] = pcg64.read_state(env.np_random)
        c.dropout[k] = dropout if dropout_generator is not None else 0.0
        if dropout_generator is not None:
            c.dropout_generators[k] = pcg64.read_state(dropout_generator)
        self._dropout_generators[k] = dropout_generator
        self._restarted[k] = False
        if self.parameters.merge is not None and env.steps_done == 0:  # a new situation: as MergeEnv._scenario_info at step 0
            self._new_situation(k, env.state[: env.n_avs, kernel.LANE].astype(np.int64))
        elif self.parameters.merge is not None:
            sl = slice(self.slot_starts[k], self.slot_starts[k + 1])
            self.ramp_av[sl], self.merge_time[sl] = env._ramp_avs, env._merge_time

    def _new_situation(self, k: int, lane: np.ndarray) -> None:
        """The merge's record of copy k's new episode: which AVs start on the ramp (``lane``: their lanes)."""
        sl = slice(self.slot_starts[k], self.slot_starts[k + 1])
        self.ramp_av[sl] = ON_RAMP_SIDE[lane]
        self.merge_time[sl] = np.nan

    def step(self, actions: np.ndarray) -> tuple[BatchStep, Starts, dict[str, Any], np.ndarray]:
        """Step every copy with one meta-action per slot (int array (slots,)), beginning a new
        episode wherever one ended: the step, the new episodes, the slot arrays
        (:meth:`slot_arrays`) and every slot's reward in the reward mode."""
        actions = np.asarray(actions, dtype=np.int64)
        steps_before = self.copies.steps.copy()
        result, starts = step_copies(
            self.states, self.offsets, self.slot_starts, actions, self.copies, self.parameters, respawn=True
        )
        self.states, self.offsets, self._stale = result.states[: result.offsets[-1]], result.offsets, True
        self._restarted |= starts.restarted
        if self.parameters.merge is not None:
            merged = self.ramp_av & np.isnan(self.merge_time) & ~ON_RAMP_SIDE[result.lane]
            steps = np.repeat(steps_before + 1, self.n_avs)
            self.merge_time[merged] = steps[merged] / self.envs[0].config["policy_frequency"]
            for k in np.flatnonzero(starts.restarted).tolist():
                self._new_situation(k, starts.lane[self.slot_starts[k] : self.slot_starts[k + 1]])
        arrays = self.slot_arrays(result, actions)
        return result, starts, arrays, copy_rewards(arrays["reward"], result.neighbours, self.slot_starts, self.mode)

    def slot_arrays(self, result: BatchStep, proposed: np.ndarray) -> dict[str, Any]:
        """The per-slot arrays of a step (:func:`~sb3_marl.envs.batch_kernel.step_report`) with
        each AV's copy's mean reward (``global_reward``)."""
        arrays = step_report(result, proposed, self.envs[0].config, self.parameters.merge is not None)
        arrays["global_reward"] = copy_rewards(arrays["reward"], result.neighbours, self.slot_starts, GLOBAL)
        return arrays

    def sync(self) -> None:
        """Give every copy's env its current state, generators and supervisor setting (before
        anything reads the envs)."""
        if not self._stale:
            return
        frames, c = self.parameters.horizon.frames_per_step, self.copies
        for k, env in enumerate(self.envs):
            if self._restarted[k]:  # as the env's reset
                env.time, env.steps, env.n_hdvs = 0, 0, int(c.n_hdvs[k])
                if bool(env.config["safety_supervisor"]) != bool(c.supervise[k]):
                    env.configure(with_supervisor(None, bool(c.supervise[k])))
            for _ in range(int(c.steps[k]) - env.steps_done):
                env.time += 1.0 / env.config["policy_frequency"]  # as the env's own steps add it up
            env.state = self.states[self.offsets[k] : self.offsets[k + 1]].copy()
            env.steps, env.done = int(c.steps[k]) * frames, False
            pcg64.write_state(env.np_random, c.generators[k])
            generator = self._dropout_generators[k]
            if generator is not None:
                pcg64.write_state(generator, c.dropout_generators[k])
            if self.parameters.merge is not None:
                sl = slice(self.slot_starts[k], self.slot_starts[k + 1])
                env._ramp_avs, env._merge_time = self.ramp_av[sl].copy(), self.merge_time[sl].copy()
        self._restarted[:] = False
        self._stale = False


def _shared_config(env: LaneChangeEnv) -> dict[str, Any]:
    return {key: value for key, value in env.config.items() if key not in PER_COPY_KEYS}


def batchable(env: Any) -> bool:
    """Whether a copy can be stepped in a :class:`RoadBatch`: the lane change or the merge itself,
    compiled, drawing no frames."""
    return type(env) in (LaneChangeEnv, MergeEnv) and not env._uses_objects()
