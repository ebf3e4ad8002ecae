"""The PettingZoo ParallelEnv of the scenario: PettingZoo's own API and seed tests, and SuperSuit -> SB3."""

import re

import numpy as np
import pytest
import supersuit as ss
from documents import code
from pettingzoo.test import parallel_api_test, parallel_seed_test
from stable_baselines3 import PPO

from sb3_marl.envs import parallel_env
from sb3_marl.envs.reward import apply_reward_mode


@pytest.mark.parametrize("density", [1, 3])
def test_pettingzoo_parallel_api_test(density):
    parallel_api_test(parallel_env(density=density, safety_supervisor=True), num_cycles=200)


def test_pettingzoo_parallel_seed_test():
    parallel_seed_test(lambda: parallel_env(density=2, safety_supervisor=True), num_cycles=150)


def test_spaces_are_cached_per_agent_and_match_the_scenario():
    env = parallel_env(density=3)
    assert env.possible_agents == [f"av_{i}" for i in range(6)]
    for agent in env.possible_agents:
        assert env.observation_space(agent) is env.observation_space(agent)
        assert env.action_space(agent) is env.action_space(agent)
    assert env.observation_space("av_0").shape == env.env.observation_space.shape[1:]
    assert env.action_space("av_0").n == 5
    assert env.state_space.shape == (int(np.prod(env.env.observation_space.shape)),)


def test_step_gives_the_scenario_per_agent_with_masks_and_reward_modes():
    """One seeded episode through the ParallelEnv and the same actions on the raw scenario."""
    pz_local = parallel_env(density=1, n_avs=3, safety_supervisor=True)
    pz_global = parallel_env(density=1, n_avs=3, safety_supervisor=True, reward_mode="global")
    raw = parallel_env(density=1, n_avs=3, safety_supervisor=True).env
    obs, infos = pz_local.reset(seed=5)
    pz_global.reset(seed=5)
    raw_obs, raw_info = raw.reset(seed=5)
    rng = np.random.default_rng(0)
    steps = 0
    while pz_local.agents:
        for i, agent in enumerate(pz_local.agents):
            np.testing.assert_array_equal(obs[agent], raw_obs[i])
            np.testing.assert_array_equal(infos[agent]["action_mask"], raw.action_masks()[i].astype(np.int8))
            if steps:
                assert infos[agent]["rule_action"] == raw.rule_actions()[i]
        np.testing.assert_array_equal(pz_local.state(), raw_obs.reshape(-1))
        actions = {agent: int(rng.choice(np.flatnonzero(infos[agent]["action_mask"]))) for agent in pz_local.agents}
        obs, rewards, terminations, truncations, infos = pz_local.step(actions)
        _, global_rewards, *_ = pz_global.step(actions)
        raw_obs, _, terminated, truncated, raw_info = raw.step(np.array(list(actions.values())))
        assert list(rewards.values()) == pytest.approx(apply_reward_mode(raw_info, "local").tolist())
        assert list(global_rewards.values()) == pytest.approx([raw_info["rewards"].mean()] * 3)
        assert set(terminations.values()) == {terminated} and set(truncations.values()) == {truncated}
        steps += 1
    assert steps == raw.steps_done and pz_local.agents == []
    with pytest.raises(RuntimeError, match="reset"):
        pz_local.step(actions)


def test_render_rgb_array():
    env = parallel_env(density=1, render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame.ndim == 3 and frame.shape[2] == 3 and frame.any()
    env.close()


@pytest.mark.parametrize(
    "kwargs, match",
    [({"density": 4}, "density"), ({"reward_mode": "team"}, "reward_mode"), ({"n_avs": 0}, "n_avs")],
)
def test_bad_arguments_name_the_field(kwargs, match):
    with pytest.raises(ValueError, match=match):
        parallel_env(**kwargs)


def test_missing_action_names_the_agent():
    env = parallel_env(density=1, n_avs=2)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="av_1"):
        env.step({"av_0": 1})


def test_supersuit_to_sb3_ppo_learns_on_it():
    vec = ss.concat_vec_envs_v1(
        ss.pettingzoo_env_to_vec_env_v1(parallel_env(density=1, n_avs=2, safety_supervisor=True)),
        2,
        num_cpus=0,
        base_class="stable_baselines3",
    )
    vec.venv.reset(seed=0)  # SuperSuit's SB3 wrapper cannot take SB3's seed (see the docs' PettingZoo section)
    model = PPO("MlpPolicy", vec, n_steps=64, batch_size=64)
    model.learn(256)
    assert model.num_timesteps == 256 and vec.num_envs == 4
    actions, _ = model.predict(vec.reset())
    assert actions.shape == (4,)


def test_the_docs_pettingzoo_example_runs_verbatim(capsys):
    exec(
        compile(code("parameter-sharing.md", "PettingZoo: the scenario as a ParallelEnv"), "parameter-sharing.md", "exec"), {}
    )
    assert re.search(r"MA2C episode return \(local rewards\): -?\d+\.\d\d", capsys.readouterr().out)


@pytest.mark.parametrize(
    "options",
    [
        {"flatten_observations": True},
        {"action_mask_in_observation": True},
        {"flatten_observations": True, "action_mask_in_observation": True},
    ],
)
def test_other_libraries_conventions_pass_pettingzoos_tests(options):
    parallel_api_test(parallel_env(density=1, safety_supervisor=True, **options), num_cycles=100)
    env = parallel_env(density=3, **options)
    observations, infos = env.reset(seed=0)
    first = observations["av_0"]
    if options.get("action_mask_in_observation"):  # the mask in the observation, not in the info
        assert np.array_equal(first["action_mask"], env.env.action_masks()[0].astype(np.int8))
        assert "action_mask" not in infos["av_0"]
        first = first["observation"]
    assert first.ndim == (1 if options.get("flatten_observations") else 2)
    assert env.observation_space("av_0").contains(observations["av_0"])


def test_bad_convention_flags_name_the_field():
    with pytest.raises(ValueError, match="flatten_observations"):
        parallel_env(flatten_observations="yes")
    with pytest.raises(ValueError, match="observation_key"):
        parallel_env(action_mask_in_observation=True, observation_key="action_mask")


def test_the_view_key_follows_rllibs_convention_on_request():
    env = parallel_env(density=1, action_mask_in_observation=True, observation_key="observations")
    observations, _ = env.reset(seed=0)
    assert set(observations["av_0"]) == {"observations", "action_mask"}
    assert env.observation_space("av_0").contains(observations["av_0"])
