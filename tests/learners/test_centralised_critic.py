"""The centralised critic (CTDE): the global state of each AV's copy, the Dict observations of the
VecEnv, a critic that reads only the state and an actor that reads only the AV's view, every
learner that offers it, saving and loading without unpickling, evaluation and validation."""

import numpy as np
import pytest
import torch as th

from sb3_marl.algos import get_algo
from sb3_marl.algos.common.policies import CentralisedCriticPolicy, GlobalStateExtractor, LocalViewExtractor, model_policy
from sb3_marl.benchmark.grid import EXPERIMENTS, make_grid
from sb3_marl.envs import ENV_IDS
from sb3_marl.envs.observation import LOCAL_KEY, STATE_KEY, centralised_observations
from sb3_marl.evaluation import evaluate_protocols
from sb3_marl.runs.hyperparams import load_hyperparams, validate_hyperparams
from sb3_marl.runs.training import make_model, make_venv

CTDE = {"architecture": "separate", "critic": "centralised"}


def ctde_hyperparams(algo: str, density: int = 1, **overrides) -> dict:
    hyperparams = {**load_hyperparams(algo, ENV_IDS[density]), **CTDE, "n_steps": 20, **overrides}
    if algo == "mappo":
        hyperparams["batch_size"] = 20
    return hyperparams


def test_the_state_lists_every_av_of_the_copy_in_order_padded_to_the_density_maximum():
    obs = np.random.default_rng(0).uniform(-1, 1, (2, 5, 5)).astype(np.float32)
    out = centralised_observations(obs, max_avs=3)
    assert out[LOCAL_KEY] is obs and out[STATE_KEY].shape == (2, 3, 27)
    for ego in range(2):
        state = out[STATE_KEY][ego]
        np.testing.assert_array_equal(state[:, 0], [1, 1, 0])  # present
        np.testing.assert_array_equal(state[:, 1], np.eye(3)[ego])  # ego flag
        np.testing.assert_array_equal(state[:2, 2:], obs.reshape(2, -1))  # every AV's view, same order
        assert not state[2].any()  # the missing third AV: a zero row
    with pytest.raises(ValueError, match="does not fit"):
        centralised_observations(obs, max_avs=1)


def test_the_vecenv_gives_each_slot_its_view_and_its_copy_state_also_at_episode_ends():
    venv = make_venv(ENV_IDS[1], {**CTDE, "env_config": {"duration": 1.0}}, seed=0)
    obs = venv.reset()
    assert obs[LOCAL_KEY].shape == (6, 5, 5) and obs[STATE_KEY].shape == (6, 3, 27)  # copies of 1, 2, 3 AVs
    assert venv.observation_space.contains({key: value[0] for key, value in obs.items()})
    # slots 3..5 are the three AVs of copy 2: one state, each with its own ego flag
    np.testing.assert_array_equal(obs[STATE_KEY][3:, :, 2:], np.broadcast_to(obs[STATE_KEY][3, :, 2:], (3, 3, 25)))
    np.testing.assert_array_equal(obs[STATE_KEY][3:, :, 1], np.eye(3))
    np.testing.assert_array_equal(obs[STATE_KEY][3:, :, 2:], np.broadcast_to(obs[LOCAL_KEY][3:].reshape(3, -1), (3, 3, 25)))
    for _ in range(5):  # 1 s at 5 Hz: the episode ends at the 5th step at the latest
        obs, _, dones, infos = venv.step(np.zeros(6, dtype=int))
        if dones[3]:
            break
    assert dones[3:].all()
    terminal = infos[4]["terminal_observation"]
    assert set(terminal) == {LOCAL_KEY, STATE_KEY} and terminal[STATE_KEY].shape == (3, 27)
    np.testing.assert_array_equal(
        terminal[STATE_KEY][:, 2:], np.stack([infos[i]["terminal_observation"][LOCAL_KEY] for i in range(3, 6)]).reshape(3, -1)
    )
    assert venv.action_masks().shape == (6, 5)
    venv.close()


@pytest.mark.parametrize("algo", ["ma2c", "mappo", "maacktr"])
def test_each_actor_critic_learner_trains_saves_and_loads_a_centralised_critic(algo, tmp_path):
    hyperparams = ctde_hyperparams(algo, supervisor_dropout=0.5, intervention_penalty=5.0)
    validate_hyperparams(algo, hyperparams, ENV_IDS[1])
    venv = make_venv(ENV_IDS[1], hyperparams, seed=0)
    model = make_model(algo, venv, hyperparams, seed=0).learn(20 * venv.num_envs)
    policy = model.policy
    assert isinstance(policy, CentralisedCriticPolicy)
    assert isinstance(policy.pi_features_extractor, LocalViewExtractor)
    assert isinstance(policy.vf_features_extractor, GlobalStateExtractor)

    obs = venv.reset()
    tensors = policy.obs_to_tensor(obs)[0]
    other_state = {**tensors, STATE_KEY: th.zeros_like(tensors[STATE_KEY])}
    with th.no_grad():  # the actor reads only the AV's view, the critic only the state
        th.testing.assert_close(
            policy.get_distribution(tensors).distribution.probs, policy.get_distribution(other_state).distribution.probs
        )
        assert not th.allclose(policy.predict_values(tensors), policy.predict_values(other_state))

    model.save(tmp_path / "model.zip")
    loaded = get_algo(algo).load(tmp_path / "model.zip")  # the safe loader: nothing unpickled
    assert loaded.observation_space == model.observation_space
    with th.no_grad():
        th.testing.assert_close(loaded.policy.predict_values(tensors), policy.predict_values(tensors))
    venv.close()


def test_the_supervisor_teacher_reads_dict_observations():
    hyperparams = ctde_hyperparams("ma2c", safety_loss_coef=1.0, env_config={"safety_supervisor": True})
    venv = make_venv(ENV_IDS[1], hyperparams, seed=0)
    model = make_model("ma2c", venv, hyperparams, seed=0).learn(20 * venv.num_envs)
    assert (model.rollout_extras.executed >= 0).any()
    assert model.logger.name_to_value["train/safety_loss"] > 0
    venv.close()


def test_a_centralised_model_is_evaluated_on_its_actor_under_both_protocols():
    hyperparams = ctde_hyperparams("ma2c", density=3)
    venv = make_venv(ENV_IDS[3], hyperparams, seed=0)
    model = make_model("ma2c", venv, hyperparams, seed=0)
    venv.close()
    result = evaluate_protocols(model_policy(model), ENV_IDS[3], n_episodes=3, seed=10_000)
    assert {"return_mean", "supervisor_off"} <= set(result)


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"critic": "global"}, "Invalid critic='global'"),
        ({"critic": "centralised", "architecture": "shared"}, "expected 'separate'"),
        ({"critic": "centralised", "architecture": "separate", "policy": "CnnPolicy"}, "Invalid policy"),
    ],
)
def test_bad_critic_settings_are_named(overrides, message):
    with pytest.raises(ValueError, match=message):
        validate_hyperparams("ma2c", {**load_hyperparams("ma2c", ENV_IDS[1]), **overrides}, ENV_IDS[1])


def test_a_q_learner_has_no_critic_to_centralise():
    with pytest.raises(ValueError, match="available for"):
        validate_hyperparams("madqn", {**load_hyperparams("madqn", ENV_IDS[1]), "critic": "centralised"}, ENV_IDS[1])


def test_the_ctde_experiment_compares_the_same_network_with_each_critic():
    assert EXPERIMENTS["ctde"] == {
        "local critic (separate networks)": ("ma2c", "separate-networks"),
        "centralised critic": ("ma2c", "centralised-critic"),
    }
    assert {t.variant for t in make_grid("ctde", densities=(1, 3), seeds=3)} == {"separate-networks", "centralised-critic"}
    assert len(make_grid("paper", seeds=3)) == 81  # the paper's grid is unchanged
