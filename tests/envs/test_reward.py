"""Each reward term and the local reward's neighbour sets against hand-computed values."""

import math

import numpy as np
import pytest
from helpers import make

from sb3_marl.envs import default_config
from sb3_marl.envs.lane_change_env import ACTION_INDEX
from sb3_marl.envs.reward import _neighbour_matrix, _terms, reward_terms, total_reward

CONFIG = default_config()


def road(vehicles, road_length=520.0):
    """The arrays of vehicles given as (x, lane, speed), AVs first: x, lane, visible, speed."""
    x = np.array([v[0] for v in vehicles], dtype=float)
    return x, np.array([v[1] for v in vehicles]), x <= road_length, np.array([v[2] for v in vehicles], dtype=float)


def terms_of(vehicles, n_avs, crashed=None, acceleration=None, lane_change=None, config=CONFIG):
    v_min, v_max = config["reward_speed_range"]
    raw = _terms(
        *road(vehicles),
        n_avs,
        np.zeros(n_avs, bool) if crashed is None else np.asarray(crashed),
        np.zeros(n_avs) if acceleration is None else np.asarray(acceleration, float),
        np.zeros(n_avs, bool) if lane_change is None else np.asarray(lane_change),
        float(config["headway_max_distance"]),
        float(config["headway_time"]),
        float(v_min),
        float(v_max),
        float(config["harsh_acceleration_threshold"]),
    )
    return reward_terms(raw)


def test_headway_term():
    # AV0: leader 20 m ahead in its lane at 25 m/s -> log(20 / (25 * 1.2)).
    # AV1: its only leader (540 m) is past the road end -> ignored -> d = 60 m -> log(60/24) > 0 -> 0.
    # AV2: nearest leader AV1 is 260 m ahead -> capped at 60 m -> 0.
    # AV3: leader at 10 m, speed 30 m/s -> log(10 / 36).
    vehicles = [(100, 0, 25), (300, 1, 20), (40, 1, 25), (200, 0, 30), (120, 0, 20), (310, 0, 20), (540, 1, 20), (210, 0, 30)]
    terms = terms_of(vehicles, n_avs=4)
    np.testing.assert_allclose(terms["headway_distance"], [20, 60, 60, 10])
    np.testing.assert_allclose(terms["headway"], [math.log(20 / 30), 0.0, 0.0, math.log(10 / 36)])


def test_speed_term():
    vehicles = [(0, 0, 5.0), (50, 0, 10.0), (100, 0, 25.0), (150, 0, 30.0), (200, 0, 34.0)]
    np.testing.assert_allclose(terms_of(vehicles, n_avs=5)["speed"], [0.0, 0.0, 0.75, 1.0, 1.0])


def test_safety_comfort_and_total():
    vehicles = [(100, 0, 25.0), (200, 0, 25.0), (300, 0, 25.0)]
    crashed, lane_change = [True, False, False], [False, True, True]
    terms = terms_of(vehicles, 3, crashed=crashed, acceleration=[0.5, -3.0, 2.99], lane_change=lane_change)
    np.testing.assert_array_equal(terms["safety"], [-1, 0, 0])
    np.testing.assert_array_equal(terms["harsh_acceleration"], [0, 1, 0])  # |a| >= 3 m/s² is harsh
    np.testing.assert_array_equal(terms["lane_change"], [0, 1, 1])
    np.testing.assert_array_equal(terms["comfort"], [0, 2, 1])
    np.testing.assert_array_equal(terms["headway"], [0, 0, 0])  # leaders 100 m ahead -> 60 m cap -> 0
    expected = [200 * -1 + 0.75 - 0, 0.75 - 2, 0.75 - 1]
    np.testing.assert_allclose(total_reward(terms, CONFIG), expected)
    no_comfort = {**CONFIG, "comfort": False}
    np.testing.assert_allclose(total_reward(terms, no_comfort), [-200 + 0.75, 0.75, 0.75])
    weighted = {**CONFIG, "safety_weight": 10.0, "speed_weight": 2.0, "comfort_weight": 0.5}
    np.testing.assert_allclose(total_reward(terms, weighted), [-10 + 1.5, 1.5 - 1.0, 1.5 - 0.5])


def test_neighbour_sets():
    # AVs: 0 lane0 x100, 1 lane0 x150, 2 lane0 x200, 3 lane1 x120, 4 lane1 x300, 5 past the road end;
    # HDVs in between never count and never hide an AV.
    vehicles = [(100, 0, 25), (150, 0, 25), (200, 0, 25), (120, 1, 25), (300, 1, 25), (530, 0, 25), (125, 0, 25)]
    x, lane, visible, _ = road(vehicles)
    sets = [set(np.flatnonzero(row)) for row in _neighbour_matrix(x, lane, visible, 6)]
    assert sets[0] == {0, 1, 3}
    assert sets[1] == {0, 1, 2, 3, 4}
    assert sets[2] == {1, 2, 3, 4}
    assert sets[3] == {0, 1, 3, 4}
    assert sets[4] == {2, 3, 4}
    assert sets[5] == {5}


class TestInSimulation:
    """Terms computed by the real env after a step, checked against its post-step state."""

    def test_headway_and_speed_after_a_step(self):
        env = make(1, n_avs=1)
        env.reset(seed=0)
        env.place(avs=[(100.0, 0, 25.0)], hdvs=[(125.0, 0, 25.0), (110.0, 1, 25.0)])
        _, _, terminated, _, info = env.step(np.array([ACTION_INDEX["IDLE"]]))
        assert not terminated
        av, leader = env.road.vehicles[0], env.road.vehicles[1]
        d, v = leader.position[0] - av.position[0], av.speed
        assert info["headway"][0] == pytest.approx(d)
        assert info["reward_terms"]["headway"][0] == pytest.approx(min(math.log(d / (1.2 * v)), 0.0))
        assert info["reward_terms"]["speed"][0] == pytest.approx((v - 10) / 20)
        expected = 4 * min(math.log(d / (1.2 * v)), 0.0) + (v - 10) / 20 - info["reward_terms"]["comfort"][0]
        assert info["rewards"][0] == pytest.approx(expected)

    def test_lane_change_and_harsh_braking_are_penalised(self):
        env = make(1, n_avs=2)
        env.reset(seed=0)
        env.place(avs=[(100.0, 0, 25.0), (300.0, 0, 25.0)])
        _, _, _, _, info = env.step(np.array([ACTION_INDEX["LANE_RIGHT"], ACTION_INDEX["SLOWER"]]))
        np.testing.assert_array_equal(info["lane_change"], [True, False])
        accel = info["acceleration"]
        assert abs(accel[0]) < 3.0 and accel[1] <= -3.0  # 25 -> 20 m/s set-point brakes hard
        assert accel[1] == pytest.approx((env.avs[1].speed - 25.0) * 5)  # mean over the 0.2 s step
        np.testing.assert_array_equal(info["reward_terms"]["comfort"], [1.0, 1.0])
        speed_terms = (info["speed"] - 10) / 20
        np.testing.assert_allclose(info["rewards"], speed_terms - 1.0)

    def test_crash_ends_episode_for_all_avs(self):
        env = make(1, n_avs=2)
        env.reset(seed=0)
        env.place(avs=[(100.0, 0, 30.0), (300.0, 1, 25.0)], hdvs=[(106.0, 0, 5.0)])
        _, reward, terminated, truncated, info = env.step(np.array([ACTION_INDEX["IDLE"]] * 2))
        assert terminated and not truncated
        np.testing.assert_array_equal(info["crashed"], [True, False])
        assert info["reward_terms"]["safety"][0] == -1.0
        assert info["rewards"][0] < -199.0
        assert reward == pytest.approx(info["rewards"].mean())
