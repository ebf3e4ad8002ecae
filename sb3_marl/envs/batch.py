"""Every copy of a scenario stepped in one compiled call (:class:`RoadBatch`).

The copies' states lie in one array and one call of
:func:`~sb3_marl.envs.batch_kernel.step_copies` steps them all (the supervisor, the frames of the
step, observations, rewards, neighbour sets, masks, the rule driver's actions) and begins a new
episode where one ended: the step a single scenario env takes as a batch of one, and the spawn its
reset draws, from the env's own generator state (:mod:`~sb3_marl.sim.pcg64`), so the same seeds
give the same episodes (tests/envs/test_batch.py compares them step by step). The scenario envs
spawn the episodes of a seeded reset into the batch's :class:`~sb3_marl.envs.roads.Roads`, where
their roads live.
Units: m, m/s, m/s², s, Hz.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sb3_marl.envs.batch_kernel import BatchStep, CopyState, Starts, copy_rewards, step_copies, step_report
from sb3_marl.envs.lane_change_env import LaneChangeEnv
from sb3_marl.envs.merge_env import MergeEnv
from sb3_marl.envs.reward import REWARD_MODES
from sb3_marl.envs.roads import Roads

#: Config keys that may differ between the copies of one batch (or between episodes of a copy).
PER_COPY_KEYS = ("n_avs", "safety_supervisor", "supervisor_shadow")


class RoadBatch:
    """The copies of one scenario config (lane change or merge; they may differ only in
    :data:`PER_COPY_KEYS`) stepped together, each new episode begun inside the step. The copies'
    envs keep reading and writing their roads, which now live in the batch's
    :class:`~sb3_marl.envs.roads.Roads` (:attr:`roads`): a reset, ``place`` or anything else an env
    does is the batch's state at once. On the merge it also keeps which AVs started on the ramp
    and when they reached the main road (the env's ``ramp_av`` and ``merge_time``).

    :param envs: the copies' unwrapped scenario envs, each reset
    :param reward_mode: ``local``, ``global`` or ``individual`` (:data:`~sb3_marl.envs.reward.REWARD_MODES`)
    """

    def __init__(self, envs: list[LaneChangeEnv], reward_mode: str) -> None:
        self.envs = envs
        self.mode = REWARD_MODES.index(reward_mode)
        self._shared = _shared_config(envs[0])
        self.check()
        self.parameters = envs[0].step_parameters()
        self.roads = Roads.join([(env._roads, env._k) for env in envs])
        self.roads.batched = True
        for k, env in enumerate(envs):
            env._home(self.roads, k)

    def check(self) -> None:
        """A RuntimeError unless every copy's config is still the batch's (a reset's options or
        ``configure`` may change it) but for :data:`PER_COPY_KEYS`."""
        for k, env in enumerate(self.envs):
            if _shared_config(env) != self._shared:
                raise RuntimeError(
                    f"Scenario copy {k}'s config changed beyond {list(PER_COPY_KEYS)}: a batch steps copies of one "
                    "config (use batched=False to step the copies one by one)."
                )

    @property
    def copies(self) -> CopyState:
        """Every copy's episode so far (the roads' :class:`~sb3_marl.envs.batch_kernel.CopyState`)."""
        return self.roads.copies

    def step(self, actions: np.ndarray) -> tuple[BatchStep, Starts, dict[str, Any], np.ndarray]:
        """Step every copy with one meta-action per slot (int array (slots,)), beginning a new
        episode wherever one ended: the step, where the next step starts, the slot arrays (the
        step's :func:`~sb3_marl.envs.batch_kernel.step_report` with each AV's copy's mean reward,
        ``global_reward``) and every slot's reward in the reward mode."""
        actions = np.asarray(actions, dtype=np.int64)
        roads = self.roads
        roads.read_lent()
        result, starts = step_copies(
            roads.states, roads.offsets, roads.slot_starts, actions, roads.copies, self.parameters, respawn=True
        )
        roads.write_lent()
        roads.set_all(result.states[: result.offsets[-1]], result.offsets)
        if self.parameters.merge is not None:  # as LaneChangeEnv._merge_info
            # each road's policy steps so far (a new episode's 0: its record is begun again below)
            steps = np.repeat(roads.copies.steps, roads.n_avs)
            roads.record_merges(slice(None), result.lane, steps, self.parameters.policy_frequency)
            for k in np.flatnonzero(starts.restarted).tolist():
                roads.new_situation(roads.slots(k), starts.lane[roads.slots(k)])
        arrays = step_report(result, actions, self.envs[0].config, self.parameters.merge is not None)
        rewards, arrays["global_reward"] = copy_rewards(arrays["reward"], result.neighbours, roads.slot_starts, self.mode)
        return result, starts, arrays, rewards


def _shared_config(env: LaneChangeEnv) -> dict[str, Any]:
    return {key: value for key, value in env.config.items() if key not in PER_COPY_KEYS}


def batchable(env: Any) -> bool:
    """Whether a copy can be stepped in a :class:`RoadBatch`: the lane change or the merge itself,
    compiled, drawing no frames."""
    return type(env) in (LaneChangeEnv, MergeEnv) and not env._uses_objects()
