"""`sb3-marl train -optimize`: rl-zoo's Optuna search on the multi-agent scenario, for real
(tiny budgets: a few hundred AV-steps per trial)."""

from pathlib import Path

import numpy as np
import optuna
import pandas as pd
import pytest
import yaml

from sb3_marl.cli import main
from sb3_marl.runs.callbacks import ScenarioEvalCallback
from sb3_marl.runs.hyperparams import load_hyperparams
from sb3_marl.runs.training import make_model, make_venv
from sb3_marl.runs.tuning import TrialPruningCallback

ENV = "sb3_marl/LaneChange-density1-v0"
ENV_NAME = "sb3_marl-LaneChange-density1-v0"
SEARCH = [
    "train",
    "--algo",
    "ma2c",
    "-optimize",
    "-n",
    "1200",
    "--n-evaluations",
    "2",
    "--eval-episodes",
    "2",
    "--n-startup-trials",
    "1",
    "-params",
    "n_steps:20",
    "--verbose",
    "0",
]


def test_a_tiny_in_memory_study_writes_the_report_and_a_usable_zoo_config(tmp_path, capsys):
    assert main([*SEARCH, "-f", str(tmp_path), "--n-trials", "3", "--study-name", "tiny", "--pruner", "none"]) == 0
    out = capsys.readouterr().out
    report = pd.read_csv(tmp_path / "ma2c" / f"report_{ENV_NAME}_tiny.csv")
    assert len(report) == 3 and set(report["state"]) <= {"COMPLETE", "PRUNED"}
    assert {"params_learning_rate", "params_ent_coef", "params_per_agent_updates"} <= set(report.columns)
    # each trial trained with its own hyperparameters: the scores are not all the same
    assert report["value"].dropna().nunique() > 1, report["value"].tolist()
    best_file = tmp_path / "ma2c" / f"best_{ENV_NAME}_tiny.yml"
    assert f"its hyperparameters as a zoo-config entry: {best_file}".lower() in out.lower()
    # trial 0 is the configuration as shipped (zoo_configs/ma2c.yml)
    shipped = load_hyperparams("ma2c", ENV)
    assert report.loc[0, "params_learning_rate"] == shipped["learning_rate"]
    assert report.loc[0, "params_per_agent_updates"] == shipped["per_agent_updates"]
    best = report.loc[report["value"].idxmax()]
    entry = yaml.safe_load(best_file.read_text())[ENV]
    assert entry["learning_rate"] == pytest.approx(best["params_learning_rate"])
    assert (entry["per_agent_updates"], entry["scale_lr_by_slots"]) == (
        best["params_per_agent_updates"],
        not best["params_per_agent_updates"],
    )
    assert entry["env_config"] == {"safety_supervisor": True} and entry["n_steps"] == 20
    assert load_hyperparams("ma2c", ENV, path=best_file)["ent_coef"] == pytest.approx(best["params_ent_coef"])
    assert not (tmp_path / "ma2c" / f"{ENV_NAME}_1").exists(), "a search writes no empty run folder"
    # the written entry trains as it is
    assert main(["train", "-c", str(best_file), "-f", str(tmp_path), "-n", "600", "--eval-freq", "-1", "--verbose", "0"]) == 0


def test_a_sqlite_study_is_resumed_by_a_second_invocation(tmp_path):
    storage = f"sqlite:///{tmp_path / 'study.db'}"
    for trials in ("2", "1"):
        argv = [
            *SEARCH,
            "--algo",
            "mappo",
            "-f",
            str(tmp_path),
            "--n-trials",
            trials,
            "--storage",
            storage,
            "--study-name",
            "resumed",
            "--sampler",
            "random",
            "--pruner",
            "none",
            "-params",
            "n_steps:32",
        ]
        assert main(argv) == 0
    study = optuna.load_study(study_name="resumed", storage=storage)
    assert len(study.trials) == 3
    assert all(t.state == optuna.trial.TrialState.COMPLETE for t in study.trials)
    # the second invocation does not repeat the first one's draws (its sampler seed moves on)
    assert len({t.params["learning_rate"] for t in study.trials}) == 3
    entry = yaml.safe_load((tmp_path / "mappo" / f"best_{ENV_NAME}_resumed.yml").read_text())[ENV]
    assert entry["policy_kwargs"].startswith("dict(net_arch=")  # rl-zoo's sampler's layers, rl-zoo's string form


def test_the_pruner_stops_a_trial_at_an_evaluation():
    study = optuna.create_study(direction="maximize", pruner=optuna.pruners.ThresholdPruner(lower=1e9))
    trial = study.ask()
    hyperparams = {**load_hyperparams("ma2c", ENV), "n_steps": 20}
    venv = make_venv(ENV, hyperparams, seed=0)
    model = make_model("ma2c", venv, hyperparams, seed=0)
    pruning = TrialPruningCallback(trial)
    evaluation = ScenarioEvalCallback(ENV, eval_freq=40, n_eval_episodes=1, callback_after_eval=pruning, verbose=0)
    model.learn(2400, callback=evaluation)
    assert pruning.is_pruned and pruning.evaluations == 1
    assert model.num_timesteps < 2400 and np.isfinite(trial.storage.get_trial(trial._trial_id).intermediate_values[1])


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--n-trials", "0"], "--n-trials"),
        (["--sampler", "grid"], "--sampler"),
        (["--pruner", "always"], "--pruner"),
        (["--n-startup-trials", "-1"], "--n-startup-trials"),
        (["--storage", "sqlite:///x.db"], "--study-name"),
        (["--storage", "study.txt", "--study-name", "s"], "--storage"),
    ],
)
def test_bad_search_flags_fail_before_any_work(extra, message, tmp_path, capsys):
    try:
        code = main([*SEARCH, "-f", str(tmp_path / "logs"), *extra])
    except SystemExit as exit_info:  # argparse's own checks
        code = exit_info.code
    assert code == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "logs").exists()
    assert not Path("x.db").exists()
