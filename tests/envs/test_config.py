"""Bad input fails at construction with one ValueError naming the key, the value and what is allowed."""

import gymnasium as gym
import numpy as np
import pytest
from helpers import make

from sb3_marl.envs import ENV_IDS, default_config, validate_config

BAD_CONFIGS = [
    ({"lane_count": 2}, "lane_count", "allowed keys"),
    ({"road_length": -520.0}, "road_length", "> 0"),
    ({"road_length": "long"}, "road_length", "a finite number"),
    ({"n_avs": 4}, "n_avs", "[1, 3]"),
    ({"n_avs": 0}, "n_avs", "integer"),
    ({"n_avs": 2.0}, "n_avs", "integer"),
    ({"density": 4}, "density", "[1, 2, 3]"),
    ({"hdv_politeness": 1.5}, "hdv_politeness", "<= 1"),
    ({"hdv_politeness": -0.1}, "hdv_politeness", ">= 0"),
    ({"hdv_b_safe": 0}, "hdv_b_safe", "> 0"),
    ({"hdv_count_range": [3, 1]}, "hdv_count_range", "min <= max"),
    ({"spawn_speed_range": [25.0]}, "spawn_speed_range", "pair"),
    ({"simulation_frequency": 16}, "simulation_frequency", "multiple of policy_frequency"),
    ({"spawn_position_noise": 20.0}, "spawn_position_noise", "never overlap"),
    ({"spawn_slots_per_lane": 2}, "spawn_slots_per_lane", "enough slots"),
    ({"comfort": "yes"}, "comfort", "true or false"),
    ({"comfort": 1}, "comfort", "true or false"),
    ({"obs_target_speed": "yes"}, "obs_target_speed", "true or false"),
    ({"lanes_count": 2.5}, "lanes_count", "integer"),
    ({"target_speeds": [30.0, 10.0]}, "target_speeds", "increasing"),
    ({"reward_speed_range": [10.0, 10.0]}, "reward_speed_range", "min < max"),
    ({"harsh_acceleration_threshold": 0.0}, "harsh_acceleration_threshold", "> 0"),
    # values that would allocate gigabytes or overflow before any check did
    ({"density": [1]}, "density", "[1, 2, 3]"),
    ({"obs_vehicles_count": 10**9}, "obs_vehicles_count", "<= 100"),
    ({"duration": 1e308}, "duration", "<= 86400"),
    ({"simulation_frequency": 5 * 10**8}, "simulation_frequency", "<= 1000"),
    ({"hdv_count_range": [0, 10**9]}, "hdv_count_range", "<= 10000"),
    ({"road_length": 1e300}, "road_length", "<= 1000000"),
]


@pytest.mark.parametrize("override, key, allowed", BAD_CONFIGS)
def test_bad_config_raises_naming_key_value_and_allowed(override, key, allowed):
    with pytest.raises(ValueError) as error:
        gym.make(ENV_IDS[1], config=override)
    message = str(error.value)
    assert key in message
    assert allowed in message
    if key != "lane_count":
        assert repr(override[key]) in message


def test_a_config_key_that_is_not_a_string_is_named():
    with pytest.raises(ValueError, match=r"Unknown config key\(s\) \[1\] for the lane-change scenario"):
        gym.make(ENV_IDS[1], config={1: 2})


def test_density_bounds_n_avs():
    make(3, n_avs=4)
    make(3, n_avs=6)
    with pytest.raises(ValueError, match=r"n_avs.*\[4, 6\]"):
        make(3, n_avs=3)


def test_reset_options_are_validated_too():
    env = make(1)
    with pytest.raises(ValueError, match="hdv_politeness"):
        env.reset(options={"config": {"hdv_politeness": 2.0}})
    assert env.config["hdv_politeness"] == 0.0  # a rejected override leaves the config unchanged


def test_default_config_is_valid_and_politeness_one_supported():
    validate_config(default_config())
    assert make(2, hdv_politeness=1.0).config["hdv_politeness"] == 1.0


def test_bad_render_mode():
    with pytest.raises(ValueError, match=r"render_mode.*rgb_array"):
        make(1).__class__(render_mode="video")


@pytest.mark.parametrize(
    "actions, match",
    [
        (np.array([1, 1]), r"shape \(3,\)"),
        (np.array([1.0, 1.0, 1.0]), "int array"),
        (np.array([1, 5, 1]), "must be in"),
        (np.array([-1, 1, 1]), "must be in"),
    ],
)
def test_bad_actions(actions, match):
    env = make(1, n_avs=3)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=match):
        env.step(actions)


@pytest.mark.parametrize("key", ["safety_weight", "headway_time", "duration", "road_length", "speed_limit", "obs_x_range"])
@pytest.mark.parametrize("value", [float("nan"), float("inf"), -float("inf")])
def test_non_finite_numbers_are_rejected_naming_the_key(key, value):
    with pytest.raises(ValueError, match=f"config\\['{key}'\\] = {value!r}: expected a finite number"):
        validate_config({**default_config(), key: value})


def test_non_finite_pairs_are_rejected():
    with pytest.raises(ValueError, match="spawn_speed_range"):
        validate_config({**default_config(), "spawn_speed_range": [25.0, float("inf")]})


def test_more_lanes_than_the_observation_distinguishes_are_rejected():
    validate_config({**default_config(), "lanes_count": 4, "spawn_slots_per_lane": 6})  # 12 m: still distinct
    with pytest.raises(ValueError, match=r"config\['lanes_count'\] = 5: expected at most 4 lanes"):
        validate_config({**default_config(), "lanes_count": 5})
    validate_config({**default_config(), "lanes_count": 5, "obs_y_range": 16.0})  # with a wider range: fine


def test_a_mix_of_ones_own_sets_any_av_count_that_fits():
    """With hdv_count_range set, n_avs leaves the density's range (twelve vehicles at density 3 with
    one to twelve AVs); the road's slots still bound it."""
    for n_avs in (1, 9, 12):
        env = make(3, n_avs=n_avs, hdv_count_range=[12 - n_avs, 12 - n_avs])
        obs, _ = env.reset(seed=0)
        assert obs.shape[0] == n_avs and env.n_hdvs == 12 - n_avs
    with pytest.raises(ValueError, match="slots"):
        make(3, n_avs=40, hdv_count_range=[40, 40])
