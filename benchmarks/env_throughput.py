"""Env-steps/s of the lane-change scenario vs stock highway-env ``highway-v0`` with the same traffic.

For each density at its maximum vehicle count (3+3, 4+4, 6+6 AVs+HDVs), both envs take uniformly
random meta-actions for every AV (seeded), resetting when an episode ends (reset time included),
on one process; and the cost of the rule driver each step reports. Prints ``name: value unit`` lines.

    python benchmarks/env_throughput.py [--steps 2000] [--densities 1 2 3]
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import gymnasium as gym
import highway_env  # noqa: F401  (registers highway-v0)

import sb3_marl  # noqa: F401  (registers our ids)
from sb3_marl.envs import DENSITIES, ENV_IDS


def stock_env(n_avs: int, n_hdvs: int) -> gym.Env:
    """highway-v0 configured like our scenario: 2 lanes, multi-agent Kinematics and meta-actions, 15/5 Hz."""
    return gym.make(
        "highway-v0",
        config={
            "lanes_count": 2,
            "controlled_vehicles": n_avs,
            "vehicles_count": n_hdvs,
            "simulation_frequency": 15,
            "policy_frequency": 5,
            "duration": 20,
            "observation": {
                "type": "MultiAgentObservation",
                "observation_config": {
                    "type": "Kinematics",
                    "vehicles_count": 5,
                    "features": ["presence", "x", "y", "vx", "vy"],
                },
            },
            "action": {"type": "MultiAgentAction", "action_config": {"type": "DiscreteMetaAction"}},
        },
    )


def ours(n_avs: int, n_hdvs: int, density: int) -> gym.Env:
    return gym.make(ENV_IDS[density], config={"n_avs": n_avs, "hdv_count_range": [n_hdvs, n_hdvs]})


def steps_per_second(env: gym.Env, steps: int, seed: int = 0) -> tuple[float, float]:
    """Random-action env-steps/s over ``steps`` steps: (resets included, ``step`` calls only)."""
    env.action_space.seed(seed)
    env.reset(seed=seed)
    episode, stepping = 0, 0.0
    start = time.perf_counter()
    for _ in range(steps):
        actions = env.action_space.sample()
        tic = time.perf_counter()
        _, _, terminated, truncated, _ = env.step(actions)
        stepping += time.perf_counter() - tic
        if terminated or truncated:
            episode += 1
            env.reset(seed=seed + episode)
    return steps / (time.perf_counter() - start), steps / stepping


def rule_action_seconds(env: gym.Env, calls: int = 20_000, seed: int = 0) -> float:
    """Seconds per ``rule_actions()`` call (the rule driver every step reports as
    ``info["rule_action"]``) on a seeded episode's start state."""
    scenario = env.unwrapped
    scenario.reset(seed=seed)
    scenario.rule_actions()  # compiled code loaded
    start = time.perf_counter()
    for _ in range(calls):
        scenario.rule_actions()
    return (time.perf_counter() - start) / calls


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=2000, help="env steps per measurement")
    parser.add_argument("--densities", type=int, nargs="+", default=sorted(DENSITIES))
    args = parser.parse_args()
    for density in args.densities:
        n_avs = DENSITIES[density]["avs"][1]
        n_hdvs = DENSITIES[density]["hdvs"][1]
        ours_sps, ours_step_only = steps_per_second(ours(n_avs, n_hdvs, density), args.steps)
        stock_sps, stock_step_only = steps_per_second(stock_env(n_avs, n_hdvs), args.steps)
        tag = f"density{density}_{n_avs}av_{n_hdvs}hdv"
        print(f"{tag}_ours_env_steps: {ours_sps:.1f} steps/s")
        print(f"{tag}_ours_agent_steps: {ours_sps * n_avs:.1f} agent-steps/s")
        print(f"{tag}_stock_env_steps: {stock_sps:.1f} steps/s")
        print(f"{tag}_stock_agent_steps: {stock_sps * n_avs:.1f} agent-steps/s")
        print(f"{tag}_speedup: {ours_sps / stock_sps:.2f} x")
        print(f"{tag}_ours_step_only: {ours_step_only:.1f} steps/s")
        print(f"{tag}_stock_step_only: {stock_step_only:.1f} steps/s")
        print(f"{tag}_step_only_speedup: {ours_step_only / stock_step_only:.2f} x")
        rule = rule_action_seconds(ours(n_avs, n_hdvs, density))
        print(f"{tag}_rule_actions: {rule * 1e6:.1f} us per step ({rule * ours_step_only:.1%} of a step, included above)")


if __name__ == "__main__":
    main()
