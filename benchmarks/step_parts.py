"""Where a VecEnv step's time goes: the parts of the compiled step per road, and the Python around it.

Records the roads' states and actions of ``--steps`` steps of the parameter-sharing VecEnv
(``--copies`` copies at ``--density``, random available actions, supervisor off), then times each
part of the compiled step on them in a compiled loop (µs per road-step): the policy step (the
frames' driving and collision test), the rule driver's actions (with the masks they read), the action masks, the
observations, the reward terms with the neighbour sets; beside them the whole compiled step
(:func:`~sb3_marl.envs.batch_kernel.step_copies`, new episodes included) and the VecEnv's step,
and a cProfile of the VecEnv's steps (its 12 largest own times). Prints ``name: value unit`` lines.

    python benchmarks/step_parts.py [--density 3] [--copies 16] [--steps 300]
"""

from __future__ import annotations

import argparse
import cProfile
import io
import os
import pstats
import time
from collections.abc import Callable

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
from numba import njit
from numba.typed import List

from sb3_marl.envs import ENV_IDS
from sb3_marl.envs.batch_kernel import CopyState, StepParameters, step_copies
from sb3_marl.envs.observation import _observe
from sb3_marl.envs.reward import _neighbour_matrix, _terms
from sb3_marl.sim import kernel
from sb3_marl.sim.drivers import rule_actions
from sb3_marl.sim.dynamics import policy_step
from sb3_marl.sim.meta_actions import available_actions
from wrappers import ParameterSharingVecEnv


@njit(cache=True)
def _policy_steps(states: List, actions: List, p: StepParameters) -> None:
    h = p.horizon
    for state, acts in zip(states, actions):
        policy_step(state, acts, h.frames_per_step, h.dt, h.lanes, h.road_end, h.speed_limit, h.ladder, acts < 0)


@njit(cache=True)
def _rule_actions(states: List, actions: List, p: StepParameters) -> None:
    h = p.horizon
    for state, acts in zip(states, actions):
        rule_actions(
            state,
            acts.size,
            None,  # the masks computed inside (the step computes them once for both)
            h.lanes,
            h.ladder,
            h.speed_limit,
            p.politeness,
            p.b_safe,
            p.lane_change_threshold,
            p.rule_acceleration_threshold,
        )


@njit(cache=True)
def _masks(states: List, actions: List, p: StepParameters) -> None:
    for state, acts in zip(states, actions):
        available_actions(state, acts.size, p.horizon.lanes, p.horizon.ladder)


@njit(cache=True)
def _observations(states: List, actions: List, p: StepParameters) -> None:
    for state, acts in zip(states, actions):
        x, v, heading = state[:, kernel.X], state[:, kernel.SPEED], state[:, kernel.HEADING]
        visible = (x <= p.horizon.road_end) & (state[:, kernel.IS_OBSTACLE] == 0)
        vx, vy = v * np.cos(heading), v * np.sin(heading)
        _observe(x, state[:, kernel.Y], vx, vy, visible, acts.size, p.rows, p.road_length, p.x_range, p.y_range, p.v_range)


@njit(cache=True)
def _rewards(states: List, actions: List, p: StepParameters) -> None:
    for state, acts in zip(states, actions):
        n = acts.size
        x, v, lane = state[:, kernel.X], state[:, kernel.SPEED], state[:, kernel.LANE].astype(np.int64)
        visible = (x <= p.horizon.road_end) & (state[:, kernel.IS_OBSTACLE] == 0)
        crashed, moved, changed = state[:n, kernel.CRASHED] > 0, np.zeros(n), np.zeros(n, dtype=np.bool_)
        thresholds = (p.headway_max_distance, p.headway_time, p.v_min, p.v_max, p.harsh_threshold)
        _terms(x, lane, visible, v, n, crashed, moved, changed, *thresholds)
        _neighbour_matrix(x, lane, visible, n)


def per_road(function: Callable[[], None], roads: int) -> float:
    """µs per road-step of ``function`` (run once first: compiled, caches warm)."""
    function()
    start = time.perf_counter()
    function()
    return (time.perf_counter() - start) / roads * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--density", type=int, default=3, choices=sorted(ENV_IDS))
    parser.add_argument("--copies", type=int, default=16)
    parser.add_argument("--steps", type=int, default=300)
    args = parser.parse_args()
    venv = ParameterSharingVecEnv(ENV_IDS[args.density], n_copies=args.copies, seed=0)
    venv.reset()
    batch, rng = venv.batch, np.random.default_rng(0)
    assert batch is not None, "a batched VecEnv"
    states, actions, inputs = List(), List(), []
    for _ in range(args.steps):
        masks = venv.action_masks()
        chosen = np.where(masks, rng.random(masks.shape), -1.0).argmax(axis=1)
        roads = batch.roads
        inputs.append((roads.states, roads.offsets.copy(), chosen, CopyState(*(a.copy() for a in batch.copies))))
        for k in range(args.copies):
            states.append(roads.rows(k).copy())
            actions.append(chosen[roads.slots(k)].copy())
        venv.step(chosen)
    n, p = len(states), batch.parameters
    print(f"vehicles_per_road: {np.mean([len(s) for s in states]):.1f}")
    print(f"avs_per_road: {np.mean([len(a) for a in actions]):.1f}")
    for name, part in [
        ("policy_step", _policy_steps),
        ("rule_actions", _rule_actions),
        ("action_masks", _masks),
        ("observations", _observations),
        ("reward_terms_and_neighbours", _rewards),
    ]:
        print(f"{name}: {per_road(lambda part=part: part(states, actions, p), n):.2f} us per road-step")

    fresh = [[CopyState(*(a.copy() for a in copies)) for *_, copies in inputs] for _ in range(2)]  # a step changes them

    def compiled() -> None:
        for (rows, offsets, chosen, _), copies in zip(inputs, fresh.pop()):
            step_copies(rows, offsets, batch.roads.slot_starts, chosen, copies, p, True)

    print(f"compiled_step: {per_road(compiled, n):.2f} us per road-step")

    def vecenv() -> None:
        for _, _, chosen, _ in inputs:
            venv.step(chosen)

    print(f"vecenv_step: {per_road(vecenv, n):.2f} us per road-step")
    profile = cProfile.Profile()
    profile.runcall(vecenv)
    text = io.StringIO()
    pstats.Stats(profile, stream=text).sort_stats("tottime").print_stats(12)
    print("cProfile of the VecEnv's steps (own time, largest 12):")
    print("\n".join(line for line in text.getvalue().splitlines() if line.strip())[-2000:])
    venv.close()


if __name__ == "__main__":
    main()
