"""MA2C network, algorithm registry, zoo configs and save/load."""

import numpy as np
import pytest
import torch as th
from gymnasium import spaces

from sb3_marl.algos import ALGOS, get_algo
from sb3_marl.algos.common.policies import MA2CFeaturesExtractor, ma2c_policy_kwargs
from sb3_marl.benchmark.grid import load_variants
from sb3_marl.cli import main
from sb3_marl.envs import ENV_IDS, MERGE_ENV_IDS
from sb3_marl.runs.hyperparams import (
    CONFIG_DIR,
    conf_file_path,
    config_file,
    load_hyperparams,
    merge_hyperparams,
    validate_hyperparams,
)
from sb3_marl.runs.training import make_model, make_venv
from wrappers import VecRewardScale


def extractor_of(model):
    """The features extractor of an actor-critic policy or of DQN's Q-network."""
    return getattr(model.policy, "q_net", model.policy).features_extractor


def test_features_extractor_splits_inputs_by_physical_unit():
    space = spaces.Box(-1, 1, (5, 5))
    extractor = MA2CFeaturesExtractor(space)
    assert extractor.features_dim == 128
    assert [layer[0].in_features for layer in extractor.units.values()] == [5, 10, 10]
    assert [layer[0].out_features for layer in extractor.units.values()] == [32, 64, 64]
    obs = th.rand(4, 5, 5) * 2 - 1
    # each unit's layer receives exactly its columns (x, y and vx, vy in the paper's order), flattened
    received = {}
    for unit, layer in extractor.units.items():
        layer.register_forward_hook(lambda module, inputs, output, unit=unit: received.update({unit: inputs[0]}))
    base = extractor(obs)
    for unit, columns in (("presence", [0]), ("position", [1, 2]), ("velocity", [3, 4])):
        assert th.equal(received[unit], obs[:, :, columns].flatten(1)), unit
    assert base.shape == (4, 128)
    with pytest.raises(ValueError, match=r"\(vehicles, 5\)"):
        MA2CFeaturesExtractor(spaces.Box(-1, 1, (25,)))


def test_the_target_speed_feature_joins_the_velocity_unit():
    """With ``obs_target_speed`` the 6th column (the ego's target speed) is a velocity input."""
    extractor = MA2CFeaturesExtractor(spaces.Box(-1, 1, (5, 6)))
    assert [layer[0].in_features for layer in extractor.units.values()] == [5, 10, 15]
    hp = {**load_hyperparams("ma2c", ENV_IDS[3]), "env_config": {"safety_supervisor": True, "obs_target_speed": True}}
    venv = make_venv(ENV_IDS[3], hp, seed=0)
    assert venv.observation_space.shape == (5, 6)
    model = make_model("ma2c", venv, hp, seed=0).learn(1_500)  # one rollout of the 15 slots
    assert model.num_timesteps == 1_500
    venv.close()


def test_shared_and_separate_architectures():
    venv = make_venv(ENV_IDS[1], {}, seed=0)
    shared = make_model("ma2c", venv, {"architecture": "shared"}, seed=0).policy
    separate = make_model("ma2c", venv, {"architecture": "separate"}, seed=0).policy
    assert shared.pi_features_extractor is shared.vf_features_extractor
    assert separate.pi_features_extractor is not separate.vf_features_extractor
    count = lambda policy: sum(p.numel() for p in policy.parameters())  # noqa: E731
    trunk = sum(p.numel() for p in shared.features_extractor.parameters())
    assert count(separate) == count(shared) + trunk
    with pytest.raises(ValueError, match="architecture='twin'"):
        ma2c_policy_kwargs("twin")


@pytest.mark.parametrize("algo", sorted(ALGOS))
@pytest.mark.parametrize("density", [1, 2, 3])
def test_every_zoo_config_builds_its_model(algo, density):
    assert config_file(algo).is_file()
    hyperparams = load_hyperparams(algo, ENV_IDS[density])
    assert hyperparams["architecture"] == "shared" and hyperparams["reward_mode"] == "local"
    venv = make_venv(ENV_IDS[density], hyperparams, seed=0)
    assert isinstance(venv, VecRewardScale) and venv.scale == 0.05
    model = make_model(algo, venv, hyperparams, seed=0)
    assert isinstance(model, get_algo(algo))
    assert isinstance(extractor_of(model), MA2CFeaturesExtractor)
    venv.close()


def test_the_safe_recipe_is_the_grid_variant_over_the_ma2c_config(tmp_path, capsys):
    """... with the authors' update cadence, which its results were measured with."""
    variants = load_variants(CONFIG_DIR / "grids" / "variants.yml")[0]
    variant = {**variants["rule-prior-agreement-0.5"], **variants["per-slot-updates"]}
    safe = conf_file_path("ma2c_safe")
    assert safe == CONFIG_DIR / "ma2c_safe.yml"
    for env_id in ENV_IDS.values():
        assert load_hyperparams("ma2c", env_id, safe) == merge_hyperparams(load_hyperparams("ma2c", env_id), variant)
    # one flag selects it; a budget below the warm start is all warm start (the rule driver imitated)
    logs = tmp_path / "logs"
    assert main(["train", "--algo", "ma2c", "--env", ENV_IDS[1], "-conf", "ma2c_safe", "-n", "1200", "-f", str(logs)]) == 0
    run = logs / "ma2c" / "sb3_marl-LaneChange-density1-v0_1"
    assert "- - prior_form\n    - agreement\n" in (run / "sb3_marl-LaneChange-density1-v0" / "config.yml").read_text()
    model = get_algo("ma2c").load(run / "sb3_marl-LaneChange-density1-v0.zip")
    assert 1_200 <= model.num_timesteps < 1_200 + 600 and model.prior_warm_start == 300_000


def test_ma2c_config_has_the_paper_settings():
    hp = load_hyperparams("ma2c", ENV_IDS[1])
    assert (hp["gamma"], hp["learning_rate"], hp["ent_coef"], hp["max_grad_norm"]) == (0.99, 5e-4, 0.01, 5.0)
    assert hp["use_rms_prop"] and hp["rms_prop_eps"] == 1e-5 and hp["n_steps"] == 100
    # one step per rollout at the learning rate x slots on the lane change; the authors' cadence on the merge
    assert (hp["per_agent_updates"], hp["scale_lr_by_slots"]) == (False, True)
    merge = load_hyperparams("ma2c", MERGE_ENV_IDS[3])
    assert (merge["per_agent_updates"], merge["scale_lr_by_slots"], merge["n_timesteps"]) == (True, False, 5e6)
    model = make_model("ma2c", make_venv(ENV_IDS[1], hp, seed=0), hp, seed=0)
    assert isinstance(model.policy.optimizer, th.optim.RMSprop)
    assert model.policy.optimizer.defaults["eps"] == 1e-5


def test_scenario_overrides_from_yaml(tmp_path):
    config = tmp_path / "ma2c.yml"
    config.write_text(
        "sb3_marl/LaneChange-density2-v0:\n  reward_mode: global\n  n_copies: 2\n"
        "  env_config: {hdv_politeness: 1.0, comfort: false}\n"
    )
    hp = load_hyperparams("ma2c", ENV_IDS[2], path=config)
    venv = make_venv(ENV_IDS[2], hp, seed=0)
    assert venv.reward_mode == "global" and venv.n_avs == [2, 3]
    assert venv.get_attr("config")[0]["hdv_politeness"] == 1.0
    assert venv.get_attr("config")[0]["comfort"] is False


@pytest.mark.parametrize(
    "algo, hyperparams, match",
    [
        ("ma2c", {"learning_rat": 1e-3}, r"Unknown hyperparameter\(s\) \['learning_rat'\].*learning_rate"),
        ("madqn", {"n_epochs": 3}, r"'n_epochs'.*exploration_fraction"),
        ("madqn", {"architecture": "separate"}, r"architecture 'separate' for 'madqn'.*\['default', 'shared'\]"),
        ("ma2c", {"policy": "LnMlpPolicy"}, r"policy 'LnMlpPolicy' for 'ma2c'.*MlpPolicy"),
        # sizes that would allocate terabytes before the first step
        ("ma2c", {"n_steps": 10**11}, r"n_steps=100000000000: expected an integer >= 1 and <= 100000"),
        ("madqn", {"buffer_size": 10**11}, r"buffer_size=100000000000: expected an integer >= 1 and <= 10000000"),
        ("ma2c", {"policy_kwargs": {"net_arch": [16000, 16000]}}, r"layers of up to 16,000 units"),
        ("ma2c", {"per_agent_updates": True, "scale_lr_by_slots": True}, r"scale_lr_by_slots: true needs per_agent_up"),
        ("ma2c", {"scale_lr_by_slots": "false"}, r"Invalid scale_lr_by_slots='false': expected true or false"),
    ],
)
def test_bad_hyperparameters(algo, hyperparams, match):
    with pytest.raises(ValueError, match=match):
        validate_hyperparams(algo, hyperparams, ENV_IDS[1])


def test_unknown_algorithm_and_missing_env_entry(tmp_path):
    with pytest.raises(ValueError, match=r"Unknown algorithm 'maddpg'.*'ma2c'.*'madqn'"):
        load_hyperparams("maddpg", ENV_IDS[1])
    config = tmp_path / "ma2c.yml"
    config.write_text("sb3_marl/LaneChange-density1-v0: {}\n")
    with pytest.raises(ValueError, match="no entry for env 'sb3_marl/LaneChange-density3-v0'"):
        load_hyperparams("ma2c", ENV_IDS[3], path=config)


@pytest.mark.parametrize("algo", ["ma2c", "madqn"])
def test_save_load_gives_the_same_actions(algo, tmp_path):
    hp = {"architecture": "shared", **({"learning_starts": 10} if algo == "madqn" else {"n_steps": 10})}
    venv = make_venv(ENV_IDS[1], hp, seed=0)
    model = make_model(algo, venv, hp, seed=0)
    model.learn(200)
    model.save(tmp_path / "model.zip")
    loaded = get_algo(algo).load(tmp_path / "model.zip", device="cpu")
    obs = venv.reset()
    for _ in range(20):
        actions, _ = model.predict(obs, deterministic=True)
        np.testing.assert_array_equal(actions, loaded.predict(obs, deterministic=True)[0])
        obs, *_ = venv.step(actions)
    assert isinstance(extractor_of(loaded), MA2CFeaturesExtractor)
    venv.close()


def test_the_loader_imports_no_learner():
    """No import circle: the loader reads the allow-list each learner class declares."""
    import subprocess
    import sys

    code = (
        "import sys, sb3_marl.algos.common.loading; print(sorted(m for m in sys.modules if m.startswith('sb3_marl.algos.')))"
    )
    learners = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout.strip()
    assert learners == "['sb3_marl.algos.common', 'sb3_marl.algos.common.loading']"


def test_one_step_per_rollout_with_the_learning_rate_times_the_slots(tmp_path):
    """``scale_lr_by_slots``: the rollout's one step takes the learning rate times the AV slots,
    as a model given that learning rate; loading it with the per-slot cadence is refused."""

    def trained(hp):
        venv = make_venv(ENV_IDS[1], hp, seed=0)
        model = make_model("ma2c", venv, hp, seed=0)
        model.learn(3 * 10 * venv.num_envs)
        venv.close()
        return model, th.nn.utils.parameters_to_vector(model.policy.parameters()).detach()

    one_step = {"n_steps": 10, "per_agent_updates": False}
    scaled, scaled_params = trained({**one_step, "learning_rate": 1e-3, "scale_lr_by_slots": True})
    _, reference = trained({**one_step, "learning_rate": 1e-3 * scaled.n_envs})
    _, unscaled = trained({**one_step, "learning_rate": 1e-3})
    assert scaled.n_envs == 6 and th.equal(scaled_params, reference) and not th.equal(scaled_params, unscaled)
    assert scaled.policy.optimizer.param_groups[0]["lr"] == 1e-3  # set back for the teacher's step
    scaled.save(tmp_path / "scaled.zip")
    with pytest.raises(ValueError, match="scale_lr_by_slots: true needs per_agent_updates: false"):
        get_algo("ma2c").load(tmp_path / "scaled.zip", per_agent_updates=True)
