"""rl-zoo's own documented ``train.py`` commands (rl-baselines3-zoo's README and docs, with our
learner and scenario in place of theirs) parse with ``sb3-marl train``: each flag either keeps
rl-zoo's meaning or is refused with a message saying why it has none here."""

from __future__ import annotations

import shlex

import pytest

from sb3_marl.cli import build_parser, main

ENV = "sb3_marl/LaneChange-density1-v0"
#: (rl-zoo's command after ``python train.py``, with ours substituted), then what it must set
MEANINGFUL = [
    (f"--algo ma2c --env {ENV}", {}),
    (
        f"--algo madqn --env {ENV} -params train_freq:4 gradient_steps:4",
        {"hyperparams": {"train_freq": 4, "gradient_steps": 4}},
    ),
    (
        f"--algo mappo --env {ENV} -n 50000 -optimize --n-trials 1000 --n-jobs 2 --sampler tpe --pruner median",
        {"n_timesteps": 50000, "optimize_hyperparameters": True, "n_trials": 1000, "n_jobs": 2},
    ),
    (f"--algo mappo --env {ENV} -conf my_config.yml", {"conf_file": "my_config.yml"}),
    (f"--algo mappo --env {ENV} --eval-freq 10000 --eval-episodes 10", {"eval_freq": 10000, "eval_episodes": 10}),
    (f"--algo madqn --env {ENV} --save-freq 100000", {"save_freq": 100000}),
    (
        f"--algo madqn --env {ENV} -i logs/madqn/model.zip -n 5000",
        {"trained_agent": "logs/madqn/model.zip", "n_timesteps": 5000},
    ),
    (f"--algo mappo --env {ENV} --env-kwargs safety_supervisor:False", {"env_kwargs": {"safety_supervisor": False}}),
    (f"--algo madqn --env {ENV} --save-replay-buffer", {"save_replay_buffer": True}),
    (f"--algo mappo --env {ENV} -P", {"progress": True}),
    (f"--algo ma2c --env {ENV} --vec-env subproc --seed 3 -tb tb --log-interval 10", {"vec_env": "subproc", "seed": 3}),
]
REFUSED = [
    f"--algo mappo --env {ENV} -uuid",
    f"--algo mappo --env {ENV} --gym-packages highway_env",
    f"--algo mappo --env {ENV} --track --wandb-project-name sb3",
    f"--algo mappo --env {ENV} --eval-episodes 10 --n-eval-envs 1",
    f"--algo mappo --env {ENV} -optimize --no-optim-plots",
]


@pytest.mark.parametrize(("command", "expected"), MEANINGFUL)
def test_rl_zoo_commands_parse_with_their_meaning(command, expected):
    args = build_parser().parse_args(["train", *shlex.split(command)])
    for key, value in expected.items():
        assert getattr(args, key) == value, key


@pytest.mark.parametrize("command", REFUSED)
def test_rl_zoo_flags_without_a_meaning_here_say_why(command, capsys):
    with pytest.raises(SystemExit) as exit_:
        build_parser().parse_args(["train", *shlex.split(command)])
    assert exit_.value.code == 2
    assert "(rl-zoo's) has no meaning here: " in capsys.readouterr().err


def test_env_kwargs_reach_the_scenario_and_the_replay_buffer_is_saved(tmp_path):
    """A short MADQN run with rl-zoo's --env-kwargs and --save-replay-buffer: the run's saved
    config has the override, and replay_buffer.npz lies beside the final model."""
    short = ["-n", "300", "--eval-freq", "-1", "-f", str(tmp_path), "--verbose", "0", "-params", "learning_starts:100"]
    code = main(["train", "--algo", "madqn", "--env", ENV, *short, "--env-kwargs", "comfort:False", "--save-replay-buffer"])
    assert code == 0
    run = tmp_path / "madqn" / "sb3_marl-LaneChange-density1-v0_1"
    assert (run / "replay_buffer.npz").is_file()
    saved = (run / "sb3_marl-LaneChange-density1-v0" / "config.yml").read_text()
    assert "comfort: false" in saved and "safety_supervisor: true" in saved  # merged into the config's env_config


#: rl-zoo's documented enjoy / record_video commands (its docs/guide/enjoy.rst, with our learner,
#: scenario and trained-agents folder in place of theirs), then what each must set
PLAY = [
    (
        "enjoy",
        f"--algo ma2c --env {ENV} --folder results/paper-grid/ -n 5000",
        {"folder": "results/paper-grid/", "n_timesteps": 5000},
    ),
    ("enjoy", f"--algo ma2c --env {ENV} -f logs/ --exp-id 0", {"folder": "logs/", "exp_id": 0}),
    ("enjoy", f"--algo ma2c --env {ENV} -f logs/ --exp-id 1 --load-best", {"exp_id": 1, "load_best": True}),
    ("enjoy", f"--algo ma2c --env {ENV} -f logs/ --exp-id 1 --load-checkpoint 10000", {"load_checkpoint": 10000}),
    ("enjoy", f"--algo ma2c --env {ENV} -f logs/ --exp-id 1 --load-last-checkpoint", {"load_last_checkpoint": True}),
    ("enjoy", f"--algo ma2c --env {ENV} --no-render -n 1000 --deterministic --seed 3 -P", {"deterministic": True, "seed": 3}),
    (
        "enjoy",
        f"--algo ma2c --env {ENV} --stochastic --env-kwargs hdv_politeness:1.0",
        {"env_kwargs": {"hdv_politeness": 1.0}},
    ),
    ("record-video", f"--algo ma2c --env {ENV} -n 1000", {"n_timesteps": 1000, "deterministic": False}),
    ("record-video", f"--algo ma2c --env {ENV} -n 1000 --load-best", {"load_best": True}),
    ("record-video", f"--algo ma2c --env {ENV} -n 1000 --load-checkpoint 10000", {"load_checkpoint": 10000}),
    ("record-video", f"--algo ma2c --env {ENV} -o videos/ --exp-id 1 --deterministic", {"output": "videos/", "exp_id": 1}),
]
REFUSED_PLAY = [
    f"enjoy --algo ma2c --env {ENV} --n-envs 4",
    f"enjoy --algo ma2c --env {ENV} --norm-reward",
    f"enjoy --algo ma2c --env {ENV} --reward-log rewards/",
    f"record-video --algo ma2c --env {ENV} --custom-objects",
    f"record-video --algo ma2c --env {ENV} --gym-packages highway_env",
]


@pytest.mark.parametrize(("command", "line", "expected"), PLAY)
def test_rl_zoo_enjoy_and_record_video_commands_parse_with_their_meaning(command, line, expected):
    args = build_parser().parse_args([command, *shlex.split(line)])
    for key, value in expected.items():
        assert getattr(args, key) == value, key


@pytest.mark.parametrize("line", REFUSED_PLAY)
def test_rl_zoo_play_flags_without_a_meaning_here_say_why(line, capsys):
    with pytest.raises(SystemExit) as exit_:
        build_parser().parse_args(shlex.split(line))
    assert exit_.value.code == 2
    assert "(rl-zoo's) has no meaning here: " in capsys.readouterr().err
