"""ParameterSharingVecEnv: slot bookkeeping, reward modes, episode ends, backends and SB3 compatibility."""

import os
import signal
import time

import gymnasium as gym
import numpy as np
import pytest
from sb3_contrib import TRPO, MaskablePPO
from stable_baselines3 import A2C, DQN, PPO
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import VecMonitor, VecNormalize

from sb3_marl.envs import ENV_IDS
from sb3_marl.envs.lane_change_env import ACTION_INDEX
from wrappers import ParameterSharingVecEnv, VecRewardScale

IDLE = ACTION_INDEX["IDLE"]


def copy_env(vec: ParameterSharingVecEnv, k: int):
    return vec.copy_env(k)


@pytest.mark.parametrize(
    "density, n_copies, expected",
    [(1, None, [1, 2, 3]), (1, 5, [1, 2, 3, 1, 2]), (2, None, [2, 3, 4]), (3, 4, [4, 5, 6, 4])],
)
def test_copies_cover_the_density_av_range(density, n_copies, expected):
    vec = ParameterSharingVecEnv(ENV_IDS[density], n_copies=n_copies)
    assert vec.n_avs == expected
    assert vec.num_envs == sum(expected)
    assert vec.slot_copy.tolist() == [k for k, n in enumerate(expected) for _ in range(n)]
    assert vec.slot_agent.tolist() == [i for n in expected for i in range(n)]
    assert vec.get_attr("n_avs") == [n for n in expected for _ in range(n)]
    assert vec.observation_space.shape == (5, 5) and vec.action_space.n == 5
    vec.close()


def test_slots_follow_the_copies_across_resets_of_different_lengths():
    """Every slot's observations, rewards and ends equal its AV's in a copy stepped directly."""
    vec = ParameterSharingVecEnv(ENV_IDS[1], reward_mode="individual", seed=11)
    direct = [gym.make(ENV_IDS[1], config={"n_avs": n}) for n in vec.n_avs]
    direct_obs = [env.reset(seed=11 + vec.slices[k].start)[0] for k, env in enumerate(direct)]
    obs = vec.reset()
    rng = np.random.default_rng(0)
    episode_ends = np.zeros(len(direct), dtype=int)
    for _ in range(250):
        np.testing.assert_array_equal(obs, np.concatenate(direct_obs))
        actions = rng.integers(0, 5, vec.num_envs)
        obs, rewards, dones, infos = vec.step(actions)
        for k, env in enumerate(direct):
            sl = vec.slices[k]
            o, _, terminated, truncated, info = env.step(actions[sl])
            np.testing.assert_allclose(rewards[sl], info["rewards"].astype(np.float32))
            assert dones[sl].tolist() == [terminated or truncated] * vec.n_avs[k]
            direct_obs[k] = o
            if terminated or truncated:
                episode_ends[k] += 1
                for agent, slot in enumerate(range(sl.start, sl.stop)):
                    np.testing.assert_array_equal(infos[slot]["terminal_observation"], o[agent])
                    assert infos[slot]["TimeLimit.truncated"] == (truncated and not terminated)
                direct_obs[k] = env.reset()[0]
    assert (episode_ends >= 2).all()  # every copy went through several resets
    vec.close()


def _placed_three_avs(reward_mode: str) -> ParameterSharingVecEnv:
    vec = ParameterSharingVecEnv(ENV_IDS[1], n_copies=1, reward_mode=reward_mode, config={"n_avs": 3}, seed=0)
    vec.reset()
    copy_env(vec, 0).place(avs=[(100.0, 0, 25.0), (150.0, 0, 27.0), (200.0, 0, 30.0)], hdvs=[(115.0, 0, 25.0)])
    return vec


def test_reward_modes():
    actions = np.array([IDLE, ACTION_INDEX["SLOWER"], IDLE])
    results = {}
    for mode in ("individual", "global", "local"):
        vec = _placed_three_avs(mode)
        _, rewards, _, _ = vec.step(actions)
        results[mode] = rewards
        own = vec.step_arrays.reward
        vec.close()
    # The situations are identical, so each mode recombines the same per-AV rewards.
    assert len(set(np.round(own, 6))) == 3
    np.testing.assert_allclose(results["individual"], own, rtol=1e-6)
    np.testing.assert_allclose(results["global"], [own.mean()] * 3, rtol=1e-6)
    # Neighbour sets of three AVs in one lane: {0, 1}, {0, 1, 2}, {1, 2} (the HDV does not hide AV 1).
    expected_local = [(own[0] + own[1]) / 2, own.mean(), (own[1] + own[2]) / 2]
    np.testing.assert_allclose(results["local"], expected_local, rtol=1e-6)


def test_time_limit_is_a_truncation_with_terminal_observation():
    vec = ParameterSharingVecEnv(
        ENV_IDS[1], n_copies=1, config={"n_avs": 1, "hdv_count_range": [0, 0], "road_length": 5000.0}, seed=0
    )
    vec.reset()
    for step in range(1, 101):
        obs, _, dones, infos = vec.step(np.array([IDLE]))
        assert dones[0] == (step == 100)
    assert infos[0]["TimeLimit.truncated"] is True
    assert infos[0]["episode"]["l"] == 100
    assert infos[0]["terminal_observation"][0, 1] > obs[0, 0, 1]  # final x progress vs the reset one
    vec.close()


def test_crash_is_a_termination_for_all_slots_of_the_copy():
    vec = ParameterSharingVecEnv(ENV_IDS[1], n_copies=2, config={"n_avs": 2}, seed=0)
    vec.reset()
    copy_env(vec, 0).place(avs=[(100.0, 0, 30.0), (300.0, 1, 25.0)], hdvs=[(106.0, 0, 5.0)])
    copy_env(vec, 1).place(avs=[(100.0, 0, 25.0), (300.0, 1, 25.0)])
    _, rewards, dones, infos = vec.step(np.full(4, IDLE))
    assert dones.tolist() == [True, True, False, False]
    assert [info["TimeLimit.truncated"] for info in infos[:2]] == [False, False]
    assert vec.step_arrays.crashed.tolist() == [True, False, False, False]
    assert rewards[0] < -99.0  # local: the crash (-200) shared with the neighbour AV
    assert "terminal_observation" not in infos[2]
    vec.close()


def test_episode_entry_is_the_slot_return():
    vec = ParameterSharingVecEnv(ENV_IDS[2], seed=3)
    vec.reset()
    returns, lengths, checked = np.zeros(vec.num_envs), np.zeros(vec.num_envs), 0
    rng = np.random.default_rng(1)
    for _ in range(60):
        _, rewards, dones, infos = vec.step(rng.integers(0, 5, vec.num_envs))
        returns += rewards
        lengths += 1
        for slot in np.flatnonzero(dones):
            assert infos[slot]["episode"]["r"] == pytest.approx(returns[slot], rel=1e-5)
            assert infos[slot]["episode"]["l"] == lengths[slot]
            returns[slot] = lengths[slot] = 0
            checked += 1
    assert checked > 5
    vec.close()


def test_dummy_and_subproc_give_identical_trajectories():
    runs = []
    for backend in ("dummy", "subproc"):
        vec = ParameterSharingVecEnv(ENV_IDS[1], n_copies=3, vec_backend=backend, seed=5)
        rng = np.random.default_rng(2)
        trajectory = [vec.reset()]
        for _ in range(80):
            obs, rewards, dones, _ = vec.step(rng.integers(0, 5, vec.num_envs))
            trajectory += [obs, rewards, dones]
        trajectory.append(np.stack(vec.env_method("action_masks")))
        vec.close()
        runs.append(trajectory)
    for a, b in zip(*runs):
        np.testing.assert_array_equal(a, b)


def test_env_method_get_set_attr_and_wrapping():
    vec = ParameterSharingVecEnv(ENV_IDS[1], seed=0, render_mode="rgb_array")
    vec.reset()
    masks = vec.env_method("action_masks")
    assert len(masks) == vec.num_envs and all(m.shape == (5,) for m in masks)
    for k in range(3):
        np.testing.assert_array_equal(np.stack(masks[vec.slices[k]]), copy_env(vec, k).action_masks())
    np.testing.assert_array_equal(vec.action_masks(), np.stack(masks))
    (mask_of_slot_3,) = vec.env_method("action_masks", indices=[3])
    np.testing.assert_array_equal(mask_of_slot_3, masks[3])
    assert vec.get_attr("n_avs", indices=[0, 5]) == [1, 3]
    vec.set_attr("test_marker", 7, indices=[1])  # on the copy's outer gym wrapper, as SB3 does
    assert vec.get_attr("test_marker", indices=[1, 2]) == [7, 7]  # slots 1 and 2 share copy 1
    with pytest.raises(AttributeError):
        vec.get_attr("test_marker", indices=[0])
    assert vec.env_is_wrapped(Monitor) == [False] * vec.num_envs
    images = vec.get_images()
    assert len(images) == 3 and all(image.ndim == 3 for image in images)
    assert vec.render().ndim == 3
    vec.close()


@pytest.mark.parametrize("density", [1, 3])
@pytest.mark.parametrize(
    "algo, kwargs",
    [
        (A2C, {"n_steps": 5}),
        (PPO, {"n_steps": 32, "batch_size": 32, "n_epochs": 1}),
        (DQN, {"learning_starts": 50, "buffer_size": 1000, "train_freq": 4}),
        (TRPO, {"n_steps": 32, "batch_size": 32}),
        (MaskablePPO, {"n_steps": 32, "batch_size": 32, "n_epochs": 1}),
    ],
)
def test_sb3_algorithms_train_through_the_wrapper(algo, kwargs, density):
    vec = ParameterSharingVecEnv(ENV_IDS[density], seed=0)
    model = algo("MlpPolicy", vec, seed=0, device="cpu", policy_kwargs={"net_arch": [32]}, **kwargs)
    model.learn(total_timesteps=300)
    assert model.num_timesteps >= 300
    actions, _ = model.predict(vec.reset(), deterministic=True)
    assert actions.shape == (vec.num_envs,)
    vec.close()


def test_maskable_ppo_only_takes_available_actions():
    vec = ParameterSharingVecEnv(ENV_IDS[1], seed=0)
    model = MaskablePPO("MlpPolicy", vec, n_steps=16, batch_size=16, n_epochs=1, seed=0, device="cpu")
    model.learn(total_timesteps=100)
    obs = vec.reset()
    for _ in range(30):
        masks = vec.action_masks()
        actions, _ = model.predict(obs, action_masks=masks)
        assert masks[np.arange(vec.num_envs), actions].all()
        obs, *_ = vec.step(actions)
    vec.close()


def test_vec_normalize_round_trip(tmp_path):
    vec = VecNormalize(ParameterSharingVecEnv(ENV_IDS[1], seed=0))
    vec.reset()
    rng = np.random.default_rng(0)
    for _ in range(40):
        vec.step(rng.integers(0, 5, vec.num_envs))
    vec.save(tmp_path / "vecnormalize.pkl")
    loaded = VecNormalize.load(tmp_path / "vecnormalize.pkl", ParameterSharingVecEnv(ENV_IDS[1], seed=0))
    np.testing.assert_array_equal(loaded.obs_rms.mean, vec.obs_rms.mean)
    np.testing.assert_array_equal(loaded.ret_rms.var, vec.ret_rms.var)
    raw = vec.get_original_obs()
    np.testing.assert_array_equal(loaded.normalize_obs(raw), vec.normalize_obs(raw))
    vec.close()
    loaded.close()


def test_evaluate_policy_under_vec_monitor():
    vec = VecMonitor(ParameterSharingVecEnv(ENV_IDS[1], seed=0))
    model = A2C("MlpPolicy", vec, n_steps=5, seed=0, device="cpu")
    rewards, lengths = evaluate_policy(model, vec, n_eval_episodes=6, return_episode_rewards=True)
    assert len(rewards) == 6 and all(1 <= n <= 100 for n in lengths)
    assert np.isfinite(rewards).all()
    vec.close()


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"reward_mode": "team"}, r"reward_mode='team'.*\['local', 'global', 'individual'\]"),
        ({"n_copies": 0}, r"n_copies=0.*>= 1"),
        ({"vec_backend": "threads"}, r"vec_backend='threads'.*\['dummy', 'subproc'\]"),
        ({"env": "CartPole-v1"}, r"CartPole-v1.*not a multi-agent"),
        ({"env": "NoSuchEnv-v0"}, r"NoSuchEnv-v0.*not a registered"),
        ({"env": lambda k: gym.make("CartPole-v1")}, "Copy 0 is not a multi-agent scenario env"),
    ],
)
def test_bad_arguments(kwargs, match):
    kwargs = {"env": ENV_IDS[1], **kwargs}
    with pytest.raises(ValueError, match=match):
        ParameterSharingVecEnv(**kwargs)


def test_bad_actions():
    vec = ParameterSharingVecEnv(ENV_IDS[1], seed=0)
    vec.reset()
    with pytest.raises(ValueError, match=r"shape \(6,\)"):
        vec.step(np.ones(5, dtype=int))
    with pytest.raises(ValueError, match=r"slots \[2\].*\[0, 4\]"):
        vec.step(np.array([1, 1, 7, 1, 1, 1]))
    with pytest.raises(ValueError, match="int array"):
        vec.step(np.ones(6))
    vec.close()


def test_dead_worker_raises_naming_the_copy():
    vec = ParameterSharingVecEnv(ENV_IDS[1], vec_backend="subproc", n_workers=2, seed=0)
    vec.reset()
    assert vec.copies.group_copies == [[0, 2], [1]]
    worker = vec.copies.groups[1].process
    worker.kill()
    worker.join()
    with pytest.raises(RuntimeError, match=r"Worker process 1 of scenario copies \[1\] died \(killed by SIGKILL"):
        vec.step(np.full(vec.num_envs, IDLE))
    vec.close()


def test_stopped_worker_times_out_naming_the_copy():
    vec = ParameterSharingVecEnv(ENV_IDS[1], vec_backend="subproc", n_workers=2, seed=0, worker_timeout=2.0)
    vec.reset()
    worker = vec.copies.groups[1].process
    os.kill(worker.pid, signal.SIGSTOP)
    try:
        start = time.perf_counter()
        with pytest.raises(TimeoutError, match=r"did not answer within 2.0 s \(alive but not responding.*copies \[1\]"):
            vec.step(np.full(vec.num_envs, IDLE))
        assert time.perf_counter() - start < 10
    finally:
        os.kill(worker.pid, signal.SIGCONT)
        vec.close()


def test_action_masks_come_from_the_current_observations():
    """The VecEnv answers ``action_masks`` from its step arrays: the same as asking each copy."""
    vec = ParameterSharingVecEnv(ENV_IDS[3], seed=0)
    vec.reset()
    rng = np.random.default_rng(0)
    for _ in range(150):  # through episode ends (auto-resets) too
        cached = np.stack(vec.env_method("action_masks"))
        asked = np.concatenate([vec.copy_env(k).action_masks() for k in range(vec.n_copies)])
        assert np.array_equal(cached, asked)
        vec.step(np.array([rng.choice(np.flatnonzero(row)) for row in cached]))
    vec.close()


def test_intervention_penalty_lowers_the_training_reward_of_overruled_slots_only():
    """Same seeds, same random actions: the penalised rewards differ from the plain ones by the
    penalty exactly where the supervisor replaced the slot's action; the step arrays keep the
    paper's reward (read through the wrapper)."""
    config = {"safety_supervisor": True}
    plain = ParameterSharingVecEnv(ENV_IDS[3], seed=5, config=config)
    penalised = VecRewardScale(ParameterSharingVecEnv(ENV_IDS[3], seed=5, config=config), 0.5, intervention_penalty=2.5)
    plain.reset(), penalised.reset()
    rng = np.random.default_rng(0)
    overruled = 0
    for _ in range(60):
        actions = rng.integers(0, 5, size=plain.num_envs)
        _, reward, _, _ = plain.step(actions)
        _, penalised_reward, _, _ = penalised.step(actions)
        intervened = plain.step_arrays.intervened
        overruled += intervened.sum()
        np.testing.assert_allclose(penalised_reward, (reward - 2.5 * intervened) * 0.5)
        np.testing.assert_array_equal(penalised.step_arrays.reward, plain.step_arrays.reward)
    assert overruled > 0  # random actions at density 3: the supervisor steps in
    with pytest.raises(ValueError, match="Invalid intervention_penalty=-1"):
        VecRewardScale(plain, intervention_penalty=-1)


def test_rule_actions_per_slot_follow_the_current_observations():
    """Each slot's rule action is its copy's rule driver on the observation the VecEnv returned
    (the new episode's after an automatic reset); after close() the cached values are refused."""
    venv = ParameterSharingVecEnv(ENV_IDS[2], seed=3)
    venv.reset()
    for _ in range(40):
        expected = np.concatenate([venv.copy_env(k).rule_actions() for k in range(venv.n_copies)])
        np.testing.assert_array_equal(venv.rule_actions(), expected)
        venv.step(np.full(venv.num_envs, ACTION_INDEX["FASTER"]))
        assert venv.step_arrays.rule_action.shape == (venv.num_envs,)
    venv.close()
    with pytest.raises(RuntimeError, match="closed"):
        venv.action_masks()
