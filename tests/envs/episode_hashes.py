"""Seeded episodes of every scenario id, with the supervisor on and off, reduced to a record that
holds on any x86-64 machine: the discrete things exactly (one SHA-256 of the action masks, the
drawn and executed actions, interventions, crash flags, neighbour sets, the rule driver's actions
and every vehicle's lane, target lane, presence, crash flag and id at each step, plus the step
count) and the floating-point things as summaries compared to a tolerance (per episode the sum,
the sum of absolute values and a fixed pseudo-random probe's dot product of the observations,
the global and per-AV rewards and every vehicle's x, y, heading and speed).

``python tests/envs/episode_hashes.py --write`` records them in episode_hashes.json (without
``--write`` it prints them); the test compares the code's against the record, so a refactor that
changes an episode shows, and a machine whose float rounding differs in the last bits does not."""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from sb3_marl.envs import SCENARIO_IDS, av_counts, make_scenario
from sb3_marl.sim import kernel

EPISODE_SEEDS = (0, 1)
RECORD = Path(__file__).with_name("episode_hashes.json")
#: A float summary matches when it is within this share of the quantity's sum of absolute values:
#: far above the rounding of a different summation order or SIMD width, far below any change of
#: the dynamics, the observations or the reward.
TOLERANCE = 1e-9
#: Per-vehicle state columns recorded exactly (integers stored as floats by the kernel).
DISCRETE_COLUMNS = [kernel.LANE, kernel.TARGET_LANE, kernel.CRASHED, kernel.PRESENT, kernel.VEHICLE_ID]
#: Per-vehicle state columns summarised as floats, each on its own (a lateral change shows beside
#: the positions along the road).
FLOAT_COLUMNS = {"x": kernel.X, "y": kernel.Y, "heading": kernel.HEADING, "speed": kernel.SPEED}


def float_summary(values: list[np.ndarray]) -> dict[str, float]:
    """Sum, sum of absolute values and dot product with a fixed probe (uniform in [-1, 1), the same
    on every machine) of all ``values`` flattened in order: a change of any element, or two
    elements swapped, moves the probe."""
    flat = np.concatenate([np.asarray(v, dtype=np.float64).ravel() for v in values])
    probe = np.random.default_rng(20_240_071).uniform(-1.0, 1.0, size=flat.size)
    return {"sum": float(flat.sum()), "abs_sum": float(np.abs(flat).sum()), "probe": float(flat @ probe)}


def episode_record(env_id: str, supervisor: bool, seed: int, version: int | None = None) -> dict[str, Any]:
    """The record of one episode at the density's largest AV count, random masked meta-actions drawn
    from ``numpy.random.default_rng(seed)`` (``version``: the supervisor's, default the scenario's)."""
    n_avs = av_counts(env_id)[-1]
    config = {"safety_supervisor": supervisor, "n_avs": n_avs, **({"supervisor_version": version} if version else {})}
    env = make_scenario(env_id, config)
    rng = np.random.default_rng(seed)
    discrete = hashlib.sha256()
    floats: dict[str, list[np.ndarray]] = {name: [] for name in ("observations", "reward", "rewards", *FLOAT_COLUMNS)}

    def vehicles() -> None:
        lanes = env.state[:, DISCRETE_COLUMNS]
        assert np.array_equal(lanes, np.rint(lanes)), "discrete state columns hold integers"
        discrete.update(np.ascontiguousarray(lanes, dtype=np.int64).tobytes())
        for name, column in FLOAT_COLUMNS.items():
            floats[name].append(env.state[:, column].copy())

    obs, info = env.reset(seed=seed)
    floats["observations"].append(obs)
    vehicles()
    done = False
    while not done:
        masks = env.action_masks()
        actions = np.array([rng.choice(np.flatnonzero(row)) for row in masks])
        obs, reward, terminated, truncated, info = env.step(actions)
        events = (masks, actions, info["executed_action"], info["intervened"], info["crashed"])
        for value in (*events, info["neighbours"], info["rule_action"]):
            discrete.update(np.ascontiguousarray(value, dtype=np.int64).tobytes())
        floats["observations"].append(obs)
        floats["reward"].append(np.array([reward]))
        floats["rewards"].append(info["rewards"])
        vehicles()
        done = terminated or truncated
    steps = int(env.steps_done)
    env.close()
    return {"steps": steps, "discrete": discrete.hexdigest(), "floats": {k: float_summary(v) for k, v in floats.items()}}


def all_records() -> dict[str, dict[str, Any]]:
    """Every scenario id with the supervisor on (its default version) and off; the lane change's
    also under its earlier defaults, version 3 (the paper's numbers as committed before version 5)
    and version 5 (the default before version 6)."""
    records = {
        f"{env_id} supervisor={on} seed={seed}": episode_record(env_id, on, seed)
        for env_id in SCENARIO_IDS
        for on in (True, False)
        for seed in EPISODE_SEEDS
    }
    for env_id in (i for i in SCENARIO_IDS if "LaneChange" in i):
        for seed in EPISODE_SEEDS:
            for version in (3, 5):
                records[f"{env_id} supervisor=v{version} seed={seed}"] = episode_record(env_id, True, seed, version=version)
    return records


def differences(recorded: dict[str, dict[str, Any]], current: dict[str, dict[str, Any]]) -> list[str]:
    """Where ``current`` departs from ``recorded``: a different set of episodes, a step count or
    discrete hash that is not equal, a float summary off by more than :data:`TOLERANCE` of the
    recorded sum of absolute values (at least 1)."""
    if list(current) != list(recorded):
        return [f"episodes {sorted(set(current) ^ set(recorded))} are in only one of the two"]
    found = []
    for key, episode in current.items():
        expected = recorded[key]
        for field in ("steps", "discrete"):
            if episode[field] != expected[field]:
                found.append(f"{key}: {field} {episode[field]} != {expected[field]}")
        for name, summary in episode["floats"].items():
            bound = TOLERANCE * max(expected["floats"][name]["abs_sum"], 1.0)
            for statistic, value in summary.items():
                if not abs(value - expected["floats"][name][statistic]) <= bound:
                    found.append(f"{key}: {name} {statistic} {value!r} != {expected['floats'][name][statistic]!r}")
    return found


if __name__ == "__main__":
    text = json.dumps(all_records(), indent=1) + "\n"
    if sys.argv[1:] == ["--write"]:
        RECORD.write_text(text)
        print(f"wrote {RECORD}")
    elif sys.argv[1:]:
        sys.exit(f"usage: python {sys.argv[0]} [--write]")
    else:
        print(text, end="")
