"""Cost of the safety supervisor beside the env step it guards, per density (one process).

For each density at its maximum vehicle count, a seeded random policy over the available actions
drives the scenario with the supervisor on; every step is timed. The supervisor runs inside the
compiled step, so its call (the compiled horizon simulation) is timed apart, on every road state
the steps started from, with the same proposed actions; beside it one prediction of the whole road over the horizon
(:func:`~sb3_marl.safety.rooms.predict`: the base path every call starts from; each replacement
candidate costs another, cut short once it cannot win) and one compiled policy step (its frames and
the collision test) are timed: their ratio says how many predictions a call makes on average, and
the prediction's cost per frame is the floor of a supervised step. The compile time of a fresh
process (numba, cached on disk after the first run) is reported apart. Prints ``name: value unit``
lines; the target is a supervisor cost under half of a step (``supervisor_share`` < 0.5 of the
step without supervisor).

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
from sb3_marl.safety.rooms import predict
from sb3_marl.sim.dynamics import policy_step
from sb3_marl.sim.kernel import COLLIDABLE


def measure(density: int, steps: int, supervisor: bool, seed: int = 0, version: int | None = None) -> dict[str, float]:
    """Seconds per step, per supervisor call, per prediction over the horizon and per compiled policy
    step over ``steps`` steps of a random masked policy (``version``: the supervisor's, default the
    scenario's)."""
    n_avs, n_hdvs = DENSITIES[density]["avs"][1], DENSITIES[density]["hdvs"][1]
    config = {"n_avs": n_avs, "hdv_count_range": [n_hdvs, n_hdvs], "safety_supervisor": supervisor}
    env = gym.make(ENV_IDS[density], config={**config, **({"supervisor_version": version} if version else {})}).unwrapped
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    episode, stepping, interventions, seen = 0, 0.0, 0, []
    for _ in range(steps):
        masks = env.action_masks()
        actions = np.array([rng.choice(np.flatnonzero(row)) for row in masks])
        seen.append((env.state.copy(), env.n_avs, actions, masks))  # the road the supervisor sees
        tic = time.perf_counter()
        _, _, terminated, truncated, info = env.step(actions)
        stepping += time.perf_counter() - tic
        interventions += int(info["intervened"].sum())
        if terminated or truncated:
            episode += 1
            env.reset(seed=seed + episode)
    # the supervisor runs inside the compiled step: timed again, apart, on the roads it saw
    supervise, h, spent = env.supervisor, env.supervisor.horizon, [0.0, 0.0, 0.0]
    for state, n_avs, actions, masks in seen:
        idle = np.zeros(n_avs, dtype=np.int64)
        tic = time.perf_counter()
        supervise(state, n_avs, actions, masks)
        spent[0] += time.perf_counter() - tic
        tic = time.perf_counter()
        predict(state, h, idle, -1, state[:, COLLIDABLE] > 0, -np.inf)
        spent[1] += time.perf_counter() - tic
        tic = time.perf_counter()
        policy_step(state, idle + 1, h.frames_per_step, h.dt, h.lanes, h.road_end, h.speed_limit, h.ladder, idle > 0)
        spent[2] += time.perf_counter() - tic
    return {
        "step": stepping / steps,
        "supervisor": spent[0] / steps,
        "prediction": spent[1] / steps,
        "policy_step": spent[2] / steps,
        "frames": float(h.frames),
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
            print(f"{at}_one_prediction: {1e3 * on['prediction']:.3f} ms ({on['frames']:.0f} frames)")
            print(f"{at}_predictions_per_supervisor_call: {on['supervisor'] / on['prediction']:.2f}")
            print(f"{at}_compiled_policy_step: {1e3 * on['policy_step']:.3f} ms (its frames and collision test)")


if __name__ == "__main__":
    main()
