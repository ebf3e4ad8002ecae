"""The rule prior: its loss and schedule, the DAgger warm start, a short run of each learner with
it, save/load of its settings, and bad input (real envs, real learners)."""

import copy

import pytest
import torch as th
from logged import Dumps
from stable_baselines3.common.logger import Logger

from sb3_marl.algos import get_algo
from sb3_marl.algos.common.rule_prior import RulePrior, prior_loss
from sb3_marl.cli import main
from sb3_marl.runs.training import make_model, make_venv

ENV = "sb3_marl/LaneChange-density1-v0"
PRIOR = {"prior": "idm-mobil", "prior_coef": 1.0, "prior_coef_final": 0.1, "prior_decay_steps": 1000}


def test_the_prior_loss_raises_the_rule_action_and_vanishes_at_zero_weight():
    """One gradient step on w · prior_loss raises the probability of the rule action (and only of
    available actions); at w = 0 the gradient is zero."""
    logits = th.zeros(4, 5, requires_grad=True)
    labels = th.tensor([4, 1, 3, 0])
    masks = th.tensor([[1, 1, 1, 1, 1], [0, 1, 1, 1, 1], [1, 1, 0, 1, 1], [1, 1, 1, 1, 0]], dtype=th.bool)
    for weight in (1.0, 0.0):
        logits.grad = None
        loss, kl = prior_loss(logits, labels, 0.1, masks)
        (weight * loss).backward()
        assert logits.grad is not None
        if weight == 0.0:
            assert th.count_nonzero(logits.grad) == 0
            continue
        assert kl.item() > 0
        stepped = logits.detach() - 1.0 * logits.grad
        before = th.softmax(logits.detach().masked_fill(~masks, -1e8), 1)[th.arange(4), labels]
        after = th.softmax(stepped.masked_fill(~masks, -1e8), 1)[th.arange(4), labels]
        assert (after > before).all()


def test_the_agreement_form_lets_go_where_the_policy_has_committed_elsewhere():
    """Both forms raise the rule action's probability; where the policy puts 1 % on it, the
    cross-entropy pulls it back hard (gradient ~ -1 on its logit), the expected disagreement hardly
    (~ -0.01): the policy may keep its own argmax without holding mass on both."""
    labels = th.tensor([0, 0])
    for form, pull in (("cross-entropy", 0.9), ("agreement", 0.02)):
        logits = th.tensor([[0.0, 0.0, 0.0, 0.0, 0.0], [-4.6, 0.0, -9.0, -9.0, -9.0]], requires_grad=True)
        loss, _ = prior_loss(logits, labels, 0.0, None, form)
        loss.backward()
        rule_gradient = logits.grad[:, 0] * 2  # the loss is a mean over the batch of 2
        assert (rule_gradient < 0).all()  # a gradient step raises the rule action's logit
        assert abs(rule_gradient[1].item()) > pull if form == "cross-entropy" else abs(rule_gradient[1].item()) < pull


def test_the_weight_falls_linearly_after_the_warm_start():
    prior = RulePrior("idm-mobil", warm_start=100, coef=1.0, coef_final=0.2, decay_steps=400)
    assert [prior.weight(t) for t in (0, 100, 300, 500, 10_000)] == pytest.approx([1.0, 1.0, 0.6, 0.2, 0.2])
    assert RulePrior().weight(0) == 0.0


def test_a_short_dagger_warm_start_raises_agreement_with_the_rule_driver():
    """A tiny DAgger warm start: the policy's most likely action agrees with the rule driver far
    more often after it than before (random init), on the states of the last round."""
    hyperparams = {"architecture": "shared", "env_config": {"safety_supervisor": True}, "n_steps": 20}
    venv = make_venv(ENV, hyperparams, seed=0)
    model = make_model("ma2c", venv, {**hyperparams, **PRIOR, "prior_warm_start": 9600}, seed=0)
    dumps = Dumps()
    model.set_logger(Logger(None, [dumps]))
    model.learn(9600 + 120)
    agreements = dumps.values("dagger/agreement")
    assert model.num_timesteps >= 9600 and len(agreements) == 8
    assert agreements[0] < 0.2 and agreements[-1] > 0.6


@pytest.mark.parametrize("algo", ["ma2c", "mappo", "maacktr"])
def test_each_actor_critic_trains_with_the_prior_and_keeps_it_when_saved(algo, tmp_path):
    """A short run with the recipe on (warm start, then the regularised loss, logged), and the
    prior's settings back after save / load."""
    form = {"ma2c": "agreement"}.get(algo, "cross-entropy")
    settings = {
        **PRIOR,
        "prior_warm_start": 1200,
        "prior_form": form,
        "n_steps": 20,
        "env_config": {"safety_supervisor": True},
    }
    if algo == "mappo":
        settings.update(batch_size=60, n_epochs=2)
    venv = make_venv(ENV, settings, seed=1)
    model = make_model(algo, venv, settings, seed=1)
    dumps = Dumps()
    model.set_logger(Logger(None, [dumps]))
    model.learn(1200 + 240, log_interval=1)
    assert len(dumps.values("dagger/agreement")) == 8 == len(dumps.values("dagger/alone/collision_rate"))
    assert all(0.1 < coef <= 1.0 for coef in dumps.values("train/prior_coef")) and dumps.values("train/prior_kl")
    model.save(tmp_path / "model.zip")
    loaded = get_algo(algo).load(tmp_path / "model.zip")
    assert loaded.rule_prior == model.rule_prior == RulePrior("idm-mobil", 1200, 1.0, 0.1, 1000, 0.0, form)


def test_madqn_starts_from_the_rule_driver_and_keeps_the_prior_when_saved(tmp_path):
    """MADQN's warm start: the rule driver's actions fill the replay buffer, and the large-margin
    loss toward the rule action makes the greedy action agree with it far more than at the start."""
    settings = {**PRIOR, "prior_warm_start": 600, "learning_starts": 0, "train_freq": 1, "gradient_steps": 4}
    settings["env_config"] = {"safety_supervisor": True}
    model = make_model("madqn", make_venv(ENV, settings, seed=2), settings, seed=2)
    initial = copy.deepcopy(model.q_net)
    dumps = Dumps()
    model.set_logger(Logger(None, [dumps]))
    model.learn(600, log_interval=1)
    buffer = model.replay_buffer
    # the rule driver drove: each stored action is the label of the previous step's next observation
    stored, previous = buffer.actions[1 : buffer.pos, :, 0], buffer.next_rule_actions[: buffer.pos - 1]
    carried = (previous >= 0) & ~buffer.dones[: buffer.pos - 1].astype(bool)
    assert carried.sum() > 300 and (stored[carried] == previous[carried]).all()
    labels = buffer.next_rule_actions[: buffer.pos].reshape(-1)
    obs = th.as_tensor(buffer.next_observations[: buffer.pos].reshape(len(labels), -1))

    def agreement(q_net) -> float:
        with th.no_grad():
            greedy = q_net(obs).argmax(dim=1).numpy()
        return float((greedy == labels)[labels >= 0].mean())

    assert agreement(model.q_net) > max(agreement(initial) + 0.3, 0.8)
    model.learn(300, reset_num_timesteps=False, log_interval=1)  # past the warm start: ε-greedy, prior decaying
    coefs = dumps.values("train/prior_coef")
    assert dumps.values("train/prior_loss") and coefs[-1] < 1.0 and all(0.1 <= coef <= 1.0 for coef in coefs)
    model.save(tmp_path / "model.zip")
    assert (
        get_algo("madqn").load(tmp_path / "model.zip").rule_prior
        == model.rule_prior
        == RulePrior("idm-mobil", 600, 1.0, 0.1, 1000)
    )


@pytest.mark.parametrize(
    ("algo", "params", "message"),
    [
        ("ma2c", "prior:'rules'", "Invalid prior='rules': expected one of ['idm-mobil']"),
        ("ma2c", "prior_warm_start:-1", "Invalid prior_warm_start=-1: expected an integer >= 0"),
        ("ma2c", "prior_warm_start:1.5", "Invalid prior_warm_start=1.5: expected an integer >= 0"),
        ("mappo", "prior_coef:'high'", "Invalid prior_coef='high': expected a finite number >= 0"),
        ("ma2c", "prior_decay_steps:0", "Invalid prior_decay_steps=0: expected an integer >= 1"),
        ("maacktr", "prior_smoothing:1.0", "Invalid prior_smoothing=1.0: expected a number in [0, 1)"),
        ("ma2c", "prior_form:'kl'", "Invalid prior_form='kl': expected one of ['cross-entropy', 'agreement']"),
        ("madqn", "prior_form:'agreement'", "Unknown hyperparameter(s) ['prior_form'] for 'madqn'"),
        ("madqn", "prior_coef_final:-1", "Invalid prior_coef_final=-1: expected a finite number >= 0"),
    ],
)
def test_bad_prior_settings_exit_2_before_any_folder(algo, params, message, tmp_path, capsys):
    assert main(["train", "--algo", algo, "-f", str(tmp_path / "logs"), "-n", "100", "-params", params]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "logs").exists()


def test_a_budget_within_the_warm_start_says_so_and_still_evaluates_the_model(tmp_path, capsys):
    """A budget the DAgger warm start spends whole (the quick start's safe recipe) calls no
    callback: the run says that its model is the imitation alone, and evaluates it once at the end
    so that ``evaluate --load-best`` finds ``best_model.zip``."""
    logs = tmp_path / "logs"
    argv = ["train", "--algo", "ma2c", "-f", str(logs), "-n", "240", "--eval-freq", "120", "--eval-episodes", "1"]
    assert main([*argv, "-params", "prior:'idm-mobil'", "prior_warm_start:600"]) == 0
    out = capsys.readouterr().out
    assert "ends within the DAgger warm start (prior_warm_start 600)" in out
    assert "No evaluation was due during training: evaluating the final model" in out
    run = logs / "ma2c" / "sb3_marl-LaneChange-density1-v0_1"
    assert (run / "best_model.zip").is_file() and (run / "evaluations.npz").is_file()
    assert main(["evaluate", "--algo", "ma2c", "-f", str(logs), "--load-best", "--eval-episodes", "1"]) == 0
