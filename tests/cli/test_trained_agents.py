"""Trained agents by name (rl-zoo's ``rl-trained-agents``): the committed grid's finished trials,
listed with their final evaluation, evaluated and filmed by name without writing into the grid."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from sb3_marl.benchmark.trained_agents import REPOSITORY_GRID
from sb3_marl.cli import main

ENV = "sb3_marl/LaneChange-density1-v0"
TRIALS = REPOSITORY_GRID / "trials"


def _grid_files():
    return sorted((path, path.stat().st_mtime_ns) for path in REPOSITORY_GRID.rglob("*"))


def test_the_listing_shows_each_name_with_its_final_evaluation(capsys):
    assert main(["trained-agents", "--algo", "ma2c", "--env", ENV]) == 0
    out = capsys.readouterr().out
    row = next(line for line in out.splitlines() if line.startswith("| safe (rule-prior-agreement-0.5) |"))
    returns = [
        json.loads((TRIALS / f"ma2c_density1_rule-prior-agreement-0.5_seed{seed}" / "result.json").read_text())[
            "paper_evaluation"
        ]["return_mean"]
        for seed in range(3)
    ]
    assert f"| 3 | {np.mean(returns):.2f} ± {np.std(returns):.2f} |" in row
    assert "| paper (default) | ma2c |" in out and "sb3-marl evaluate --algo ALGO --env ENV --trained NAME" in out


def test_a_named_agent_is_evaluated_and_filmed_without_writing_into_the_grid(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    before = _grid_files()
    # rl-zoo's spelling: -n counts env steps (150: two episodes of up to 100 steps)
    assert main(["enjoy", "--algo", "ma2c", "--env", ENV, "--trained", "safe", "-n", "150", "--no-render"]) == 0
    out = capsys.readouterr().out
    assert "| ma2c (safe) |" in out and "2 episodes, seeds 10000..10001" in out
    written = tmp_path / "logs" / "trained-agents" / "ma2c_density1_rule-prior-agreement-0.5_seed0"
    evaluation = json.loads((written / "evaluation.json").read_text())
    assert evaluation["model"].startswith(str(TRIALS)) and len(evaluation["returns"]) == 2
    # rl-zoo's `-f rl-trained-agents/`: a grid folder alone picks its paper agent; -o a folder; -n frames
    assert main(["record-video", "--algo", "ma2c", "--env", ENV, "-f", str(REPOSITORY_GRID), "-n", "12", "-o", "videos/"]) == 0
    assert re.search(r"wrote videos/sb3_marl-LaneChange-density1-v0\.mp4: 1 episode\(s\), 12 frames", capsys.readouterr().out)
    assert (tmp_path / "videos" / "sb3_marl-LaneChange-density1-v0.mp4").stat().st_size > 0
    assert _grid_files() == before


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--trained", "fastest"], "no trained agent 'fastest' (seed 0) of ma2c on sb3_marl/LaneChange-density1-v0"),
        (["--trained", "safe", "--algo", "maacktr"], "trained agents there: paper ("),
        (["--trained", "safe", "--env", "sb3_marl/Merge-density1-v0"], "no trained agent 'safe'"),
    ],
)
def test_an_unknown_name_lists_the_names_there(argv, message, capsys):
    assert main(["evaluate", "--algo", "ma2c", "--env", ENV, *argv]) == 2
    err = capsys.readouterr().err
    assert "--trained: " in err and message in err
