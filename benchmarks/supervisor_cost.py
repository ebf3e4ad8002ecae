"""Cost of the safety supervisor beside the env step it guards, per density (one process).

For each density at its maximum vehicle count, a seeded random policy over the available actions
drives the scenario with the supervisor on; every step is timed, and so is the supervisor's own
call (its prediction: array copy of the vehicle states + the compiled horizon simulation) inside
it. The compile time of a fresh process (numba, cached on disk after the first run) is reported
apart. Prints ``name: value unit`` lines; the target is a supervisor cost under half of a step
(``supervisor_share`` < 0.5 of the step without supervisor).

    python benchmarks/supervisor_cost.py [--steps 3000] [--densities 1 2 3] [--versions 3 5]

``--versions``: the supervisor's versions to time side by side in one run (default: the scenario's).
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import gymnasium as gym
import numpy as np

import sb3_marl  # noqa: F401  (registers our ids)
from sb3_marl.envs import DENSITIES, ENV_IDS
from sb3_marl.safety.supervisor import Supervisor


def measure(density: int, steps: int, supervisor: bool, seed: int = 0, version: int | None = None) -> dict[str, float]:
    """Seconds per step and per supervisor call over ``steps`` steps of a random masked policy
    (``version``: the supervisor's, default the scenario's)."""
    n_avs, n_hdvs = DENSITIES[density]["avs"][1], DENSITIES[density]["hdvs"][1]
    config = {"n_avs": n_avs, "hdv_count_range": [n_hdvs, n_hdvs], "safety_supervisor": supervisor}
    env = gym.make(ENV_IDS[density], config={**config, **({"supervisor_version": version} if version else {})}).unwrapped
    supervise, spent = Supervisor.__call__, [0.0, 0]

    def timed(*args, **kwargs):
        tic = time.perf_counter()
        result = supervise(*args, **kwargs)
        spent[0] += time.perf_counter() - tic
        spent[1] += 1
        return result

    Supervisor.__call__ = timed  # every env's supervisor, timed
    try:
        rng = np.random.default_rng(seed)
        env.reset(seed=seed)
        episode, stepping, interventions = 0, 0.0, 0
        for _ in range(steps):
            actions = np.array([rng.choice(np.flatnonzero(row)) for row in env.action_masks()])
            tic = time.perf_counter()
            _, _, terminated, truncated, info = env.step(actions)
            stepping += time.perf_counter() - tic
            interventions += int(info["intervened"].sum())
            if terminated or truncated:
                episode += 1
                env.reset(seed=seed + episode)
    finally:
        Supervisor.__call__ = supervise
    return {
        "step": stepping / steps,
        "supervisor": spent[0] / max(spent[1], 1),
        "interventions_per_step": interventions / steps,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=3000, help="env steps per measurement")
    parser.add_argument("--densities", type=int, nargs="+", default=sorted(DENSITIES))
    parser.add_argument("--versions", type=int, nargs="+", default=[None], help="supervisor versions (default: the default)")
    args = parser.parse_args()
    tic = time.perf_counter()
    measure(1, 2, supervisor=True)  # compiles, or loads the on-disk cache
    print(f"supervisor_first_call_in_process: {time.perf_counter() - tic:.2f} s")
    for density in args.densities:
        off = measure(density, args.steps, supervisor=False)
        tag = f"density{density}"
        print(f"{tag}_step_without_supervisor: {1e3 * off['step']:.3f} ms")
        for version in args.versions:
            on = measure(density, args.steps, supervisor=True, version=version)
            at = tag + (f"_v{version}" if version else "")
            print(f"{at}_step_with_supervisor: {1e3 * on['step']:.3f} ms")
            print(f"{at}_supervisor_call: {1e3 * on['supervisor']:.3f} ms")
            print(f"{at}_supervisor_share: {on['supervisor'] / off['step']:.2f} of a step without supervisor")
            print(f"{at}_interventions_per_step: {on['interventions_per_step']:.2f} AVs")


if __name__ == "__main__":
    main()
