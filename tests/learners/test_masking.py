"""Action masking: no learner ever samples or executes an unavailable meta-action."""

import numpy as np
import pytest
from stable_baselines3.common.callbacks import BaseCallback

from sb3_marl.algos import get_algo
from sb3_marl.algos.common.policies import model_policy, uses_action_masks
from sb3_marl.envs import ENV_IDS
from sb3_marl.evaluation import run_episodes
from sb3_marl.runs.hyperparams import load_hyperparams, validate_hyperparams
from sb3_marl.runs.training import make_model, make_venv

#: small settings so that every learner updates several times within the budget
QUICK = {
    "ma2c": {"n_steps": 20},
    "mappo": {"n_steps": 20, "batch_size": 60, "n_epochs": 2},
    "maacktr": {"n_steps": 20},
    "madqn": {"learning_starts": 100, "buffer_size": 5000, "exploration_fraction": 0.5},
}
LEARNERS = sorted(QUICK)


class MaskAudit(BaseCallback):
    """Checks, at every training step, each slot's action against the mask of the observation it
    was chosen on (the VecEnv's masks before the step), and counts the actions that were masked."""

    def __init__(self) -> None:
        super().__init__()
        self.steps = self.violations = self.masked_out = 0

    def _on_training_start(self) -> None:
        self.masks = np.stack(self.training_env.env_method("action_masks"))

    def _on_step(self) -> bool:
        actions = np.asarray(self.locals["actions"]).reshape(-1)
        self.violations += int((~self.masks[np.arange(actions.size), actions]).sum())
        self.masked_out += int((~self.masks).sum())
        self.steps += 1
        self.masks = np.stack(self.training_env.env_method("action_masks"))
        return True


def quick_model(algo: str, density: int = 1, **overrides):
    hyperparams = {**load_hyperparams(algo, ENV_IDS[density]), **QUICK[algo], **overrides}
    venv = make_venv(ENV_IDS[density], hyperparams, seed=0)
    return make_model(algo, venv, hyperparams, seed=0, device="cpu"), venv


@pytest.mark.parametrize("algo", LEARNERS)
def test_masked_actions_are_never_taken_in_training(algo):
    model, venv = quick_model(algo)
    assert uses_action_masks(model)
    audit = MaskAudit()
    model.learn(1200, callback=audit)
    venv.close()
    assert audit.steps == 200 and audit.masked_out > 0  # masks did exclude actions
    assert audit.violations == 0


@pytest.mark.parametrize("algo", LEARNERS)
def test_unmasked_learner_takes_masked_actions(algo):
    """The ablation (``action_masking: false``): the audit can fail, so the test above means something."""
    model, venv = quick_model(algo, action_masking=False)
    assert not uses_action_masks(model)
    audit = MaskAudit()
    model.learn(1200, callback=audit)
    venv.close()
    assert audit.violations > 0


@pytest.mark.parametrize("algo", LEARNERS)
@pytest.mark.parametrize("masking", [True, False])
def test_save_load_keeps_the_masking_setting(algo, masking, tmp_path):
    model, venv = quick_model(algo, action_masking=masking)
    model.learn(300)
    venv.close()
    model.save(tmp_path / "model.zip")
    loaded = get_algo(algo).load(tmp_path / "model.zip", device="cpu")
    assert uses_action_masks(loaded) is masking
    obs = np.zeros((4, *loaded.observation_space.shape), dtype=np.float32)
    only = np.zeros((4, 5), dtype=bool)
    only[np.arange(4), [0, 1, 2, 4]] = True  # one available action per row
    for deterministic in (True, False):
        actions, _ = loaded.predict(obs, deterministic=deterministic, action_masks=only)
        if masking:
            assert actions.tolist() == [0, 1, 2, 4]


def test_loaded_model_drives_by_hand_with_the_env_masks(tmp_path):
    model, venv = quick_model("ma2c")
    model.learn(600)
    venv.close()
    model.save(tmp_path / "ma2c.zip")
    loaded = get_algo("ma2c").load(tmp_path / "ma2c.zip", device="cpu")
    import gymnasium as gym

    env = gym.make(ENV_IDS[1], config={"n_avs": 3, "safety_supervisor": True}).unwrapped
    obs, _ = env.reset(seed=0)
    for _ in range(20):
        masks = env.action_masks()
        actions, _ = loaded.predict(obs, action_masks=masks)
        assert masks[np.arange(3), actions].all()
        obs, _, terminated, truncated, _ = env.step(actions)
        if terminated or truncated:
            break
    records = run_episodes(env, model_policy(loaded), 2, seed=5)
    assert all(r.length > 0 for r in records)


def test_action_masking_must_be_a_boolean():
    with pytest.raises(ValueError, match="action_masking"):
        validate_hyperparams("ma2c", {"action_masking": "yes"})


class ExecutedRecorder(BaseCallback):
    def __init__(self) -> None:
        super().__init__()
        self.executed, self.intervened = [], []

    def _on_step(self) -> bool:
        self.executed.append(self.training_env.step_arrays.executed_action.tolist())
        self.intervened.append(self.training_env.step_arrays.intervened.tolist())
        return True


@pytest.mark.parametrize("stored", ["proposed", "executed"])
def test_the_learner_stores_the_configured_action(stored):
    import copy

    import torch as th

    from sb3_marl.runs.callbacks import StoreExecutedActions

    model, venv = quick_model("ma2c", density=3)
    before = copy.deepcopy(model.policy)
    recorder = ExecutedRecorder()
    callbacks = [StoreExecutedActions(), recorder] if stored == "executed" else [recorder]
    model.learn(20 * venv.num_envs, callback=callbacks)  # one rollout of 20 steps
    venv.close()
    buffer = model.rollout_buffer  # flattened by the update: (slots * steps, ...), slot-major
    executed = np.array(recorder.executed)  # (steps, slots)
    assert np.array(recorder.intervened).any()  # the supervisor did replace actions
    stored_actions = buffer.actions.reshape(venv.num_envs, -1).T
    assert np.array_equal(stored_actions, executed) is (stored == "executed")
    with th.no_grad():  # stored log-probabilities are those of the stored actions (ratio 1)
        distribution = before.get_distribution(th.as_tensor(buffer.observations), action_masks=buffer.action_masks)
        log_probs = distribution.log_prob(th.as_tensor(buffer.actions.reshape(-1)))
    assert np.allclose(log_probs.numpy(), buffer.log_probs.reshape(-1), atol=1e-5)


def test_stored_actions_must_be_known():
    from sb3_marl.runs.hyperparams import validate_scenario

    with pytest.raises(ValueError, match="stored_actions"):
        validate_scenario({"stored_actions": "both"}, ENV_IDS[1])


@pytest.mark.parametrize("algo", LEARNERS)
def test_sampled_evaluation_is_reproducible_and_leaves_the_global_generators_alone(algo):
    """Sampled actions (torch for the actor-critics, numpy's global generator for MADQN's ε-greedy)
    are seeded per episode by the episode runner: the same seeds give the same episodes whatever
    the global random state before, and that state is as it was after."""
    import gymnasium as gym
    import torch as th

    model, venv = quick_model(algo)
    venv.close()
    if algo == "madqn":
        model.exploration_rate = 0.5  # half the actions drawn at random
    env = gym.make(ENV_IDS[1], config={"n_avs": 2}).unwrapped
    runs = []
    for global_seed in (1, 2):
        np.random.seed(global_seed)
        th.manual_seed(global_seed)
        records = run_episodes(env, model_policy(model), 2, seed=7)
        runs.append([(r.episode_return, r.lane_changes, r.accelerations) for r in records])
        # both global streams continue as if no episode had been played
        assert np.random.random() == np.random.RandomState(global_seed).random()
        assert th.rand(1).item() == th.rand(1, generator=th.Generator().manual_seed(global_seed)).item()
    assert runs[0] == runs[1]
