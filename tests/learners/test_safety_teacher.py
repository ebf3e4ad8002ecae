"""The safety supervisor as a teacher: the auxiliary loss on its interventions, supervisor dropout
in training, their validation, and a short run of each learner with the recipe on (real envs)."""

import json

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.callbacks import BaseCallback

from sb3_marl.algos.a2c import MaskableA2C
from sb3_marl.algos.dqn import MaskableDQN, large_margin_loss
from sb3_marl.cli import main
from wrappers import ParameterSharingVecEnv

ENV = "sb3_marl/LaneChange-density1-v0"
SUPERVISED = {"safety_supervisor": True}


class InterventionCounter(BaseCallback):
    """Counts the slot-steps the supervisor overruled, from the VecEnv's step arrays."""

    def __init__(self) -> None:
        super().__init__()
        self.count = 0

    def _on_rollout_start(self) -> None:
        self.count = 0

    def _on_step(self) -> bool:
        arrays = self.training_env.step_arrays
        self.count += int((arrays.intervened & ~arrays.exited).sum())
        return True


@pytest.fixture(scope="module")
def teacher_model() -> tuple[MaskableA2C, InterventionCounter]:
    """MA2C (random init: many unsafe proposals) after one 40-step rollout and update."""
    venv = ParameterSharingVecEnv(ENV, config=SUPERVISED, seed=0)
    model = MaskableA2C("MlpPolicy", venv, n_steps=40, safety_loss_coef=1.0, seed=0)
    counter = InterventionCounter()
    model.learn(40 * venv.num_envs, callback=counter)
    return model, counter


def test_the_recorder_labels_exactly_the_intervened_steps(teacher_model):
    model, counter = teacher_model
    labels = model.rollout_extras.executed
    assert counter.count > 0 and (labels >= 0).sum() == counter.count
    assert set(np.unique(labels[labels >= 0])) <= set(range(5))


def _probabilities(model: MaskableA2C, labels: np.ndarray) -> np.ndarray:
    buffer = model.rollout_buffer
    flat = labels.swapaxes(0, 1).reshape(-1)
    chosen = np.flatnonzero(flat >= 0)
    with th.no_grad():
        distribution = model.policy.get_distribution(
            th.as_tensor(buffer.observations[chosen]), action_masks=buffer.action_masks[chosen]
        )
        return distribution.log_prob(th.as_tensor(flat[chosen])).exp().numpy()


def test_the_loss_is_zero_without_interventions_and_raises_the_executed_actions_probability(teacher_model):
    model, _ = teacher_model
    before = [p.detach().clone() for p in model.policy.parameters()]
    assert model.safety_step(np.full_like(model.rollout_extras.executed, -1)) == 0.0
    assert all(th.equal(a, b) for a, b in zip(before, model.policy.parameters()))  # no step at all

    labels = model.rollout_extras.executed.copy()
    probability_before = _probabilities(model, labels)
    loss = model.safety_step(labels)
    assert loss == pytest.approx(-np.log(probability_before).mean(), rel=1e-5)
    assert _probabilities(model, labels).mean() > probability_before.mean()


def test_the_dqn_margin_loss():
    venv = ParameterSharingVecEnv(ENV, config=SUPERVISED, seed=0)
    model = MaskableDQN("MlpPolicy", venv, safety_loss_coef=1.0, learning_starts=0, seed=0)
    q = th.tensor([[1.0, 2.0, 0.0, 0.0, 0.0], [3.0, 0.0, 0.0, 0.0, 0.0]])
    assert large_margin_loss(q, th.tensor([-1, -1]), model.SAFETY_MARGIN).item() == 0.0
    # row 0: the supervisor chose action 0, whose Q is below action 1's: 2 + 0.8 - 1
    assert large_margin_loss(q, th.tensor([0, -1]), model.SAFETY_MARGIN).item() == pytest.approx(1.8)
    # row 1: action 0 already beats the others by more than the margin
    assert large_margin_loss(q, th.tensor([-1, 0]), model.SAFETY_MARGIN).item() == pytest.approx(0.0)
    model.learn(300)
    replayed = model.replay_buffer.executed_actions[: model.replay_buffer.pos]
    assert (replayed >= 0).any() and (replayed[replayed >= 0] < 5).all()


def _interventions_and_crashes(dropout: float, seed: int = 0, steps: int = 300) -> tuple[int, int, list]:
    venv = ParameterSharingVecEnv(ENV, config=SUPERVISED, seed=seed, supervisor_dropout=dropout)
    venv.reset()
    rng = np.random.default_rng(0)
    interventions = crashes = 0
    trace = []
    for _ in range(steps):
        _, rewards, _, _ = venv.step(rng.integers(0, 5, venv.num_envs))
        interventions += int(venv.step_arrays.intervened.sum())
        crashes += int(venv.step_arrays.crashed.sum())
        trace.append(rewards.copy())
    venv.close()
    return interventions, crashes, trace


def test_supervisor_dropout_turns_the_supervisor_off_per_episode_reproducibly():
    on_interventions, on_crashes, _ = _interventions_and_crashes(0.0)
    off_interventions, off_crashes, _ = _interventions_and_crashes(1.0)
    assert on_interventions > 0 and on_crashes == 0
    assert off_interventions == 0 and off_crashes > 0
    _, half_crashes, first = _interventions_and_crashes(0.5)
    _, _, again = _interventions_and_crashes(0.5)
    assert half_crashes > 0 and np.array_equal(np.array(first), np.array(again))


@pytest.mark.parametrize(
    ("algo", "params", "message"),
    [
        ("ma2c", "safety_loss_coef:-1", "Invalid safety_loss_coef=-1"),
        ("madqn", "safety_loss_coef:'x'", "Invalid safety_loss_coef='x'"),
        ("ma2c", "supervisor_dropout:1.5", "Invalid supervisor_dropout=1.5"),
        ("maacktr", "safety_loss_coef:1.0", "Unknown hyperparameter(s) ['safety_loss_coef']"),
    ],
)
def test_bad_recipe_keys_exit_2_naming_the_key(algo, params, message, tmp_path, capsys):
    assert main(["train", "--algo", algo, "-f", str(tmp_path / "logs"), "-n", "100", "-params", params]) == 2
    assert message in capsys.readouterr().err and not (tmp_path / "logs").exists()


@pytest.mark.parametrize("algo", ["ma2c", "mappo", "madqn"])
def test_a_short_run_of_each_learner_with_the_recipe(algo, tmp_path):
    logs = tmp_path / "logs"
    assert (
        main(
            [
                "train",
                "--algo",
                algo,
                "-f",
                str(logs),
                "-n",
                "1200",
                "--eval-freq",
                "600",
                "--eval-episodes",
                "2",
                "--verbose",
                "0",
                "-params",
                "safety_loss_coef:1.0",
                "supervisor_dropout:0.5",
            ]
        )
        == 0
    )
    assert main(["evaluate", "--algo", algo, "-f", str(logs), "--eval-episodes", "2"]) == 0
    run = logs / algo / "sb3_marl-LaneChange-density1-v0_1"
    result = json.loads((run / "evaluation.json").read_text())
    assert {"collision_rate", "yields_per_episode", "lane_changes_per_episode"} <= set(result["supervisor_off"])
    from sb3_marl.algos import get_algo

    assert get_algo(algo).load(run / "sb3_marl-LaneChange-density1-v0.zip").safety_loss_coef == 1.0
    with np.load(run / "evaluations.npz") as log:
        assert log["supervisor_off_results"].shape == log["results"].shape
