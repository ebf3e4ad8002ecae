"""The real scenario env with config overrides, and seeded rollouts of it (hand-made traffic: ``env.place``)."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

import sb3_marl  # noqa: F401
from sb3_marl.envs import ENV_IDS, LaneChangeEnv


def make(density: int = 1, **config: Any) -> LaneChangeEnv:
    """The registered env of ``density`` with ``config`` overrides, unwrapped."""
    return gym.make(ENV_IDS[density], config=config).unwrapped


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
