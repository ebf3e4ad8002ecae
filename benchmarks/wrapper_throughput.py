"""Agent-steps/s through ParameterSharingVecEnv vs stepping the scenario copies directly, and dummy vs subproc.

Random actions, seeded, the same for every variant; copies cover the density's AV range
(``--copies`` of them). Shared 2-core VMs vary by tens of percent from run to run, so the
variants are measured in turn ``--repeats`` times and the best of each is kept (as ``timeit``
does). Prints ``name: value unit`` lines.

    python benchmarks/wrapper_throughput.py [--density 1] [--copies 4] [--steps 1000] [--repeats 3]
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import gymnasium as gym
import numpy as np

from sb3_marl.envs import ENV_IDS
from wrappers import ParameterSharingVecEnv


def direct_agent_steps_per_second(env_id: str, slices: list[slice], steps: int, seed: int = 0) -> float:
    """Step the copies one after the other without the wrapper (same seeds and actions); auto-reset by hand."""
    envs = [gym.make(env_id, config={"n_avs": sl.stop - sl.start}) for sl in slices]
    for env, sl in zip(envs, slices):
        env.reset(seed=seed + sl.start)  # the wrapper's seeding
    rng = np.random.default_rng(seed)
    n_slots = slices[-1].stop
    start = time.perf_counter()
    for _ in range(steps):
        actions = rng.integers(0, 5, n_slots)
        for env, sl in zip(envs, slices):
            _, _, terminated, truncated, _ = env.step(actions[sl])
            if terminated or truncated:
                env.reset()
    return steps * n_slots / (time.perf_counter() - start)


def wrapper_agent_steps_per_second(vec: ParameterSharingVecEnv, steps: int, seed: int = 0) -> float:
    vec.seed(seed)
    vec.reset()
    rng = np.random.default_rng(seed)
    start = time.perf_counter()
    for _ in range(steps):
        vec.step(rng.integers(0, 5, vec.num_envs))
    return steps * vec.num_envs / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--density", type=int, default=1, choices=sorted(ENV_IDS))
    parser.add_argument("--copies", type=int, default=4)
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    env_id = ENV_IDS[args.density]

    dummy = ParameterSharingVecEnv(env_id, n_copies=args.copies, vec_backend="dummy", seed=0)
    subproc = ParameterSharingVecEnv(env_id, n_copies=args.copies, vec_backend="subproc", seed=0)
    n_avs = dummy.n_avs
    direct = through_dummy = through_subproc = 0.0
    for _ in range(args.repeats):
        direct = max(direct, direct_agent_steps_per_second(env_id, dummy.slices, args.steps))
        through_dummy = max(through_dummy, wrapper_agent_steps_per_second(dummy, args.steps))
        through_subproc = max(through_subproc, wrapper_agent_steps_per_second(subproc, args.steps))
    dummy.close()
    subproc.close()

    tag = f"density{args.density}_{args.copies}copies_{sum(n_avs)}slots"
    print(f"{tag}_direct: {direct:.0f} agent-steps/s")
    print(f"{tag}_wrapper_dummy: {through_dummy:.0f} agent-steps/s")
    print(f"{tag}_wrapper_overhead: {100 * (1 - through_dummy / direct):.1f} %")
    print(f"{tag}_wrapper_subproc: {through_subproc:.0f} agent-steps/s")
    print(f"{tag}_subproc_speedup: {through_subproc / through_dummy:.2f} x")
    print(f"cpu_count: {os.cpu_count()} cores")


if __name__ == "__main__":
    main()
