"""Builders of hand-made traffic situations on the real scenario env."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

import sb3_marl  # noqa: F401
from sb3_marl.envs import ENV_IDS, LaneChangeEnv
from sb3_marl.envs.road import configure_hdv

Vehicle = tuple[float, int, float]  # x [m], lane, speed [m/s]


def make(density: int = 1, **config: Any) -> LaneChangeEnv:
    """The registered env of ``density`` with ``config`` overrides, unwrapped."""
    return gym.make(ENV_IDS[density], config=config).unwrapped


def place(env: LaneChangeEnv, avs: list[Vehicle], hdvs: list[Vehicle] = ()) -> None:
    """Replace the traffic of a reset env by AVs and HDVs at given (x, lane, speed)."""
    assert len(avs) == env.n_avs
    road = env.road
    lanes = road.network.lanes_list()
    road.vehicles = []
    env.avs = [
        env.simulator.av(road, lanes[lane].position(x, 0), 0.0, speed, target_speeds=env.config["target_speeds"])
        for x, lane, speed in avs
    ]
    hdv_objects = []
    for x, lane, speed in hdvs:
        hdv = env.simulator.hdv(road, lanes[lane].position(x, 0), 0.0, speed)
        configure_hdv(hdv, env.config)
        hdv_objects.append(hdv)
    road.vehicles = [*env.avs, *hdv_objects]
    env.controlled_vehicles = list(env.avs)
    env.n_hdvs = len(hdv_objects)
    env._exited = np.zeros(env.n_avs, dtype=bool)


def rollout(env: gym.Env, seed: int, steps: int, action_seed: int = 0) -> list[np.ndarray]:
    """Observations of a seeded random-action rollout, resetting on episode end."""
    rng = np.random.default_rng(action_seed)
    obs, _ = env.reset(seed=seed)
    trajectory = [obs]
    episode = 0
    for _ in range(steps):
        actions = rng.integers(0, 5, size=env.unwrapped.n_avs)
        obs, reward, terminated, truncated, info = env.step(actions)
        trajectory.append(np.concatenate([obs.ravel(), [reward], info["rewards"]]))
        if terminated or truncated:
            episode += 1
            obs, _ = env.reset(seed=seed + episode)
            trajectory.append(obs)
    return trajectory
