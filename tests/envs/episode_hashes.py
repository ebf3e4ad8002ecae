"""Seeded episodes of every scenario id, with the supervisor on and off, reduced to one SHA-256
each: observations, rewards (global and per AV), action masks, executed actions, crash flags,
neighbour sets, the rule driver's actions and the step count.
``python tests/envs/episode_hashes.py > tests/envs/episode_hashes.json`` records them; the test
compares the code's against the record, so a refactor that changes an episode shows."""

from __future__ import annotations

import hashlib
import json

import numpy as np

from sb3_marl.envs import SCENARIO_IDS, av_counts, make_scenario

EPISODE_SEEDS = (0, 1)


def episode_hash(env_id: str, supervisor: bool, seed: int, version: int | None = None) -> str:
    """The hash of one episode at the density's largest AV count, random masked meta-actions
    drawn from ``numpy.random.default_rng(seed)`` (``version``: the supervisor's, default the scenario's)."""
    n_avs = av_counts(env_id)[-1]
    config = {"safety_supervisor": supervisor, "n_avs": n_avs, **({"supervisor_version": version} if version else {})}
    env = make_scenario(env_id, config)
    rng = np.random.default_rng(seed)
    digest = hashlib.sha256()
    obs, info = env.reset(seed=seed)
    digest.update(np.ascontiguousarray(obs, dtype=np.float64).tobytes())
    done = False
    while not done:
        masks = env.action_masks()
        actions = np.array([rng.choice(np.flatnonzero(row)) for row in masks])
        obs, reward, terminated, truncated, info = env.step(actions)
        step = (obs, reward, masks, info["executed_action"], info["crashed"], info["rewards"])
        for value in (*step, info["neighbours"], info["rule_action"]):
            digest.update(np.ascontiguousarray(value, dtype=np.float64).tobytes())
        done = terminated or truncated
    digest.update(str(env.steps_done).encode())
    env.close()
    return digest.hexdigest()


def all_hashes() -> dict[str, str]:
    """Every scenario id with the supervisor on (its default version) and off; the lane change's
    also under its earlier default, version 3 (the paper's numbers as committed before version 5)."""
    hashes = {
        f"{env_id} supervisor={on} seed={seed}": episode_hash(env_id, on, seed)
        for env_id in SCENARIO_IDS
        for on in (True, False)
        for seed in EPISODE_SEEDS
    }
    for env_id in (i for i in SCENARIO_IDS if "LaneChange" in i):
        for seed in EPISODE_SEEDS:
            hashes[f"{env_id} supervisor=v3 seed={seed}"] = episode_hash(env_id, True, seed, version=3)
    return hashes


if __name__ == "__main__":
    print(json.dumps(all_hashes(), indent=1))
