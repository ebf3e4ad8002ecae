"""The fast simulator classes against highway-env's own: identical trajectories, same seed, same actions."""

import numpy as np
import pytest
from helpers import make
from highway_env.road.lane import StraightLane
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.controller import MDPVehicle

from sb3_marl.envs.simulator import (
    FAST,
    STOCK,
    FastStraightLane,
    arcsin,
    arctan,
    cos,
    sin,
    tan,
)

#: Mostly IDLE, so that episodes last and HDVs overtake by MOBIL, with some lane changes and speed
#: changes of the AVs; uniform random actions end most episodes in a crash within a few steps.
ACTION_PROBABILITIES = {"uniform": [0.2] * 5, "cruise": [0.04, 0.8, 0.04, 0.06, 0.06]}


def vehicle_states(env) -> np.ndarray:
    """Every vehicle's position, heading, speed, lanes, crash flag and low-level action."""
    return np.array(
        [
            [*v.position, v.heading, v.speed, v.lane_index[2], v.target_lane_index[2], v.crashed,
             v.action["steering"], v.action["acceleration"]]
            for v in env.road.vehicles
        ],
        dtype=np.float64,
    )


def trajectory(simulator, density: int, seed: int, steps: int, policy: str) -> tuple[list[np.ndarray], dict]:
    """States, observations and rewards of a seeded rollout, and counts of what it exercised."""
    env = make(density)
    env.simulator = simulator
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    record = [vehicle_states(env)]
    seen = {"episodes": 0, "crashes": 0, "hdv_lane_changes": 0, "turned_vehicle_steps": 0}
    for _ in range(steps):
        targets = [v.target_lane_index for v in env.road.vehicles[env.n_avs :]]
        obs, reward, terminated, truncated, info = env.step(rng.choice(5, env.n_avs, p=ACTION_PROBABILITIES[policy]))
        record += [vehicle_states(env), obs, np.array([reward, *info["rewards"]])]
        hdvs = env.road.vehicles[env.n_avs :]
        seen["hdv_lane_changes"] += sum(a != v.target_lane_index for a, v in zip(targets, hdvs))
        seen["turned_vehicle_steps"] += sum(v.heading != 0 for v in env.road.vehicles)
        if terminated or truncated:
            seen["episodes"] += 1
            seen["crashes"] += terminated
            env.reset(seed=seed + 1000 * seen["episodes"])
            record.append(vehicle_states(env))
    return record, seen


@pytest.mark.parametrize("density", [1, 2, 3])
@pytest.mark.parametrize("policy", ["uniform", "cruise"])
def test_fast_simulator_matches_highway_env(density, policy):
    fast, seen = trajectory(FAST, density, seed=density, steps=300, policy=policy)
    stock, _ = trajectory(STOCK, density, seed=density, steps=300, policy=policy)
    assert seen["crashes"] >= 3  # collisions (and the impact they cause) were exercised
    assert seen["turned_vehicle_steps"] > 50  # vehicles off the straight heading: general trigonometry
    if policy == "cruise":
        assert seen["hdv_lane_changes"] >= 2  # MOBIL lane changes of the HDVs
    assert len(fast) == len(stock)
    for k, (a, b) in enumerate(zip(fast, stock)):
        np.testing.assert_array_equal(a, b, err_msg=f"record {k} differs")


def test_fast_classes_are_highway_env_classes():
    env = make(2)
    env.reset(seed=0)
    assert isinstance(env.road.network.lanes_list()[0], StraightLane)
    assert all(isinstance(av, MDPVehicle) for av in env.avs)
    assert all(isinstance(hdv, IDMVehicle) for hdv in env.road.vehicles[env.n_avs :])


def test_fast_lane_needs_an_axis_parallel_lane():
    lane = FastStraightLane([0.0, 4.0], [520.0, 4.0])
    assert lane.local_coordinates(np.array([100.0, 5.0])) == StraightLane([0.0, 4.0], [520.0, 4.0]).local_coordinates(
        np.array([100.0, 5.0])
    )
    with pytest.raises(ValueError, match="parallel to an axis"):
        FastStraightLane([0.0, 0.0], [100.0, 10.0])


@pytest.mark.parametrize("value", [0.0, -0.0, 1e-300, -0.3, 0.7, 1.2])
def test_trigonometry_shortcuts_equal_numpy(value):
    for fast, stock in ((sin, np.sin), (cos, np.cos), (tan, np.tan), (arctan, np.arctan)):
        assert np.array_equal(np.float64(fast(value)), stock(value)) and np.signbit(fast(value)) == np.signbit(stock(value))
    if abs(value) <= 1:
        assert np.array_equal(np.float64(arcsin(value)), np.arcsin(value))
        assert np.signbit(arcsin(value)) == np.signbit(np.arcsin(value))
