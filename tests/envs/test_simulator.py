"""The state array against highway-env's objects: the spawn equals highway-env's constructors, and
objects built from a state capture back to it exactly."""

import numpy as np
import pytest
from helpers import make
from highway_env.road.lane import StraightLane
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.controller import MDPVehicle

from sb3_marl.sim.road import configure_hdv, make_road, vehicle_state
from sb3_marl.sim.simulator import capture, vehicle_objects


def highway_env_vehicles(env, x, lane, speed) -> list:
    """highway-env's own construction of the scenario's vehicles (as its envs spawn them)."""
    road = make_road(env.config, env.np_random)
    lanes = road.network.lanes_list()
    vehicles = []
    for i, (xi, li, vi) in enumerate(zip(x.tolist(), lane.tolist(), speed.tolist())):
        position, heading = lanes[int(li)].position(xi, 0.0), lanes[int(li)].heading_at(xi)
        if i < env.n_avs:
            vehicles.append(MDPVehicle(road, position, heading, vi, target_speeds=env.config["target_speeds"]))
        else:
            hdv = IDMVehicle(road, position, heading, vi)
            configure_hdv(hdv, env.config)
            vehicles.append(hdv)
    return vehicles


@pytest.mark.parametrize("density", [1, 2, 3])
def test_spawned_state_is_what_highway_env_constructors_give(density):
    env = make(density)
    for seed in range(20):
        env.reset(seed=seed)
        state = env.state
        x, lane, speed = state[:, 0], state[:, 4], state[:, 3]
        np.testing.assert_array_equal(capture(highway_env_vehicles(env, x, lane, speed), env.road.network), state)
        np.testing.assert_array_equal(vehicle_state(env.config, x, lane, speed, env.n_avs), state)


@pytest.mark.parametrize("density", [1, 3])
def test_objects_built_from_the_state_capture_back_to_it(density):
    env = make(density)
    rng = np.random.default_rng(0)
    checked = {"crashed": 0, "turned": 0, "changing_lane": 0}
    for seed in range(5):
        env.reset(seed=seed)
        for _ in range(40):
            vehicles = vehicle_objects(env.road, env.state, env.config)
            np.testing.assert_array_equal(capture(vehicles, env.road.network), env.state)
            checked["crashed"] += int(env.state[:, 9].any())
            checked["turned"] += int((env.state[:, 2] != 0).any())
            checked["changing_lane"] += int((env.state[:, 4] != env.state[:, 5]).any())
            *_, terminated, truncated, _ = env.step(rng.choice(5, env.n_avs, p=[0.1, 0.6, 0.1, 0.1, 0.1]))
            if terminated or truncated:
                np.testing.assert_array_equal(
                    capture(vehicle_objects(env.road, env.state, env.config), env.road.network), env.state
                )
                checked["crashed"] += int(env.state[:, 9].any())
                break
    assert all(count > 0 for count in checked.values()), checked


def test_the_road_shows_the_state_as_highway_env_objects():
    env = make(2)
    env.reset(seed=0)
    assert isinstance(env.road.network.lanes_list()[0], StraightLane)
    assert all(type(av) is MDPVehicle for av in env.avs)
    assert all(type(hdv) is IDMVehicle for hdv in env.road.vehicles[env.n_avs :])
    env.step(np.ones(env.n_avs, dtype=int))
    np.testing.assert_array_equal(capture(env.road.vehicles, env.road.network), env.state)  # rebuilt after the step


def test_an_unknown_simulator_is_refused():
    env = make(1)
    env.simulator = "fast"
    with pytest.raises(ValueError, match=r"Invalid simulator='fast': expected one of \('compiled', 'stock'\)"):
        env.reset(seed=0)
