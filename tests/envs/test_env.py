"""Gymnasium API, observation layout, episode ends, seeding, action masks and rendering."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from helpers import make, rollout
from highway_env.envs.common.action import DiscreteMetaAction

from sb3_marl.envs import ENV_IDS
from sb3_marl.envs.lane_change_env import ACTION_INDEX

IDLE = ACTION_INDEX["IDLE"]


@pytest.mark.parametrize("density, n_avs", [(1, 1), (1, 3), (2, 4), (3, 6)])
def test_spaces_and_gymnasium_checker(density, n_avs):
    env = gym.make(ENV_IDS[density], config={"n_avs": n_avs})
    assert env.observation_space.shape == (n_avs, 5, 5)
    assert env.action_space.nvec.tolist() == [5] * n_avs
    check_env(env.unwrapped, skip_render_check=True)
    obs, _ = env.reset(seed=1)
    assert obs.dtype == np.float32 and env.observation_space.contains(obs)


def test_default_n_avs_is_density_maximum():
    assert [make(d).n_avs for d in (1, 2, 3)] == [3, 4, 6]


def test_observation_values_in_a_constructed_situation():
    env = make(1, n_avs=2)
    env.reset(seed=0)
    obs, _ = env.place(
        avs=[(100.0, 0, 25.0), (400.0, 1, 30.0)],
        hdvs=[(130.0, 1, 20.0), (90.0, 0, 27.0), (60.0, 1, 26.0), (20.0, 0, 25.0), (530.0, 1, 30.0)],
    )
    np.testing.assert_allclose(
        obs[0],
        [
            [1, 100 / 520, 0, 25 / 45, 0],  # ego, absolute
            [1, -10 / 150, 0, 2 / 45, 0],  # nearest |dx| first: the HDV 10 m behind
            [1, 30 / 150, 4 / 12, -5 / 45, 0],
            [1, -40 / 150, 4 / 12, 1 / 45, 0],
            [1, -80 / 150, 0, 0, 0],  # the HDV at 20 m; AV1 (300 m away) is out of range
        ],
        rtol=1e-6,
        atol=1e-7,
    )
    # AV1 sees nothing within 150 m: the vehicle at 530 m is past the road end; absent rows are 0.
    np.testing.assert_allclose(obs[1, 0], [1, 400 / 520, 4 / 12, 30 / 45, 0], rtol=1e-6)
    assert not obs[1, 1:].any()


def test_the_target_speed_feature_adds_the_egos_set_point_and_changes_nothing_else():
    """``obs_target_speed`` (not the paper's): a 6th column, the ego's target speed / 45 m/s on the
    ego row (it moves with FASTER/SLOWER at once, while vx converges over ~1 s), 0 elsewhere."""
    paper, extended = make(3, n_avs=4), make(3, n_avs=4, obs_target_speed=True)
    assert extended.observation_space.shape == (4, 5, 6) and paper.observation_space.shape == (4, 5, 5)
    obs_paper, _ = paper.reset(seed=3)
    obs, _ = extended.reset(seed=3)
    initial = np.array([av.target_speed for av in extended.avs])
    for step in range(6):
        assert extended.observation_space.contains(obs)
        np.testing.assert_array_equal(obs[..., :5], obs_paper)  # the same episode, the same 5 features
        targets = np.array([av.target_speed for av in extended.avs])
        np.testing.assert_allclose(obs[:, 0, 5], targets / 45, rtol=1e-6)
        assert not obs[:, 1:, 5].any()
        actions = np.full(4, ACTION_INDEX["SLOWER"] if step < 2 else IDLE)
        obs, *_ = extended.step(actions)
        obs_paper, *_ = paper.step(actions)
    # SLOWER sets the target one 5 m/s step below the ladder value nearest the current speed
    # (highway-env's MDPVehicle), so two in a row 0.2 s apart move it once
    np.testing.assert_allclose(obs[:, 0, 5] * 45, initial - 5, rtol=1e-6)


def test_observation_stays_normalised():
    env = make(3)
    for obs in rollout(env, seed=0, steps=60):
        if obs.ndim == 3:
            assert np.all(np.abs(obs) <= 1.0)
            assert np.all(np.isin(obs[..., 0], [0.0, 1.0]))


def test_same_seed_same_episode_and_different_seeds_differ():
    a = rollout(make(2), seed=7, steps=80)
    b = rollout(make(2), seed=7, steps=80)
    c = rollout(make(2), seed=8, steps=80)
    assert len(a) == len(b) and all(np.array_equal(x, y) for x, y in zip(a, b))
    assert not np.array_equal(a[0], c[0])


def test_time_limit_truncates_after_100_steps():
    env = make(1, n_avs=1, hdv_count_range=[0, 0], road_length=5000.0)
    env.reset(seed=0)
    for step in range(1, 101):
        _, _, terminated, truncated, info = env.step(np.array([IDLE]))
        assert not terminated
        assert truncated == (step == 100)
    assert info["step"] == 100


def test_vehicles_past_the_road_end_leave_the_scenario():
    env = make(1, n_avs=2)
    env.reset(seed=0)
    env.place(avs=[(517.0, 0, 30.0), (480.0, 0, 25.0)], hdvs=[(518.0, 1, 30.0)])
    obs, _, terminated, truncated, info = env.step(np.array([IDLE, IDLE]))
    assert not terminated and not truncated
    np.testing.assert_array_equal(info["exited"], [True, False])
    assert not env.avs[0].collidable
    assert len(env.road.vehicles) == 2  # the HDV that left is removed, the AV keeps driving
    assert not obs[1, 1:].any()  # AV1 no longer sees AV0
    assert info["headway"][1] == 60.0
    np.testing.assert_array_equal(info["neighbours"], [[True, False], [False, True]])
    for _ in range(20):
        _, _, terminated, truncated, info = env.step(np.array([IDLE, IDLE]))
        if truncated:
            break
    assert truncated and not terminated and info["exited"].all() and info["step"] < 100


def test_action_mask_matches_highway_env_available_actions():
    env = make(3)
    reference = DiscreteMetaAction(env, target_speeds=env.config["target_speeds"])
    rng = np.random.default_rng(0)
    checked = 0
    for seed in range(10):
        env.reset(seed=seed)
        for _ in range(10):
            mask = env.action_masks()
            for i, av in enumerate(env.avs):
                reference.controlled_vehicle = av
                assert sorted(np.flatnonzero(mask[i])) == sorted(reference.get_available_actions())
                checked += 1
            actions = np.where(rng.random(env.n_avs) < 0.5, IDLE, rng.integers(0, 5, env.n_avs))
            *_, terminated, truncated, info = env.step(actions)
            np.testing.assert_array_equal(info["action_mask"], env.action_masks())
            if terminated or truncated:
                break
    assert checked > 100


def test_scalar_action_for_a_single_av():
    env = make(1, n_avs=1)
    env.reset(seed=0)
    env.step(np.int64(IDLE))


def test_rgb_array_render_headless():
    env = gym.make(ENV_IDS[1], render_mode="rgb_array")
    env.reset(seed=0)
    env.step(env.action_space.sample())
    frame = env.render()
    assert frame.ndim == 3 and frame.shape[2] == 3 and frame.dtype == np.uint8
    assert frame.std() > 0
    env.close()
