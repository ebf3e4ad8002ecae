"""The commands the README and the docs show work exactly as written: the Quick start's main job,
every command of the Command line page and of its hyperparameter search, run verbatim (the page
states the short budget appended to `train`)."""

import shlex
import subprocess
import sys
from pathlib import Path

import pytest
from documents import REPO, commands, read, section

#: appended to the Command line page's train commands, as the page says
SHORT_BUDGET = {"first": ["-n", "1200", "--eval-freq", "600"], "resumed": ["-n", "2400"]}


def test_the_command_line_section_runs_verbatim(tmp_path):
    commands_ = commands("command-line.md", "Command line")
    assert commands_[0].startswith("sb3-marl train") and len(commands_) >= 8
    executable = Path(sys.executable).parent / "sb3-marl"
    trains = 0
    for line in commands_:
        argv = shlex.split(line)
        assert argv[0] == "sb3-marl", line
        if argv[1] == "train":
            argv += SHORT_BUDGET["resumed" if "-i" in argv else "first"]
            trains += 1
        completed = subprocess.run([str(executable), *argv[1:]], cwd=tmp_path, capture_output=True, text=True, timeout=600)
        assert completed.returncode == 0, f"{line}\n{completed.stdout[-2000:]}\n{completed.stderr[-2000:]}"
    assert trains == 4
    run = tmp_path / "logs" / "ma2c" / "sb3_marl-LaneChange-density1-v0_1"
    assert (run / "best_model.zip").is_file() and (run / "evaluation.json").is_file()
    assert (tmp_path / "logs" / "summary.md").is_file()
    assert (tmp_path / "logs" / "plots" / "eval_return.png").is_file()


def test_the_quick_start_main_job_runs_verbatim(tmp_path):
    """`make run`, as written (the other Quick start command, `make test`, is this suite), with its
    log folder (the Makefile's RUN_LOGS) in a temporary folder: the test never writes into the
    checkout's own logs/."""
    quick_start = commands("README.md", "Quick start")
    assert quick_start == ["make run", "make test"]
    checkout_logs = sorted((REPO / "logs").rglob("*")) if (REPO / "logs").exists() else []
    completed = subprocess.run(
        [*shlex.split(quick_start[0]), f"RUN_LOGS={tmp_path / 'logs'}"], cwd=REPO, capture_output=True, text=True, timeout=1800
    )
    assert completed.returncode == 0, completed.stdout[-3000:] + completed.stderr[-3000:]
    out = completed.stdout
    assert "| ma2c |" in out and "| idm-mobil |" in out and "sampled actions (the authors' protocol)" in out
    assert "| on |" in out and "| off |" in out  # both supervisor protocols
    assert "TensorBoard: " in out and "eval_return.png" in out
    assert "| ma2c (ma2c_safe) |" in out and "DAgger warm start, round 8/8" in out  # the safe recipe's row
    # every row of the README's table, learned ones included, is this run's, to the digit
    rows = [
        line
        for line in section("README.md", "Quick start").splitlines()
        if line.startswith(("| ma2c |", "| ma2c (ma2c_safe) |", "| random |", "| cruise |", "| idm-mobil |"))
    ]
    assert len(rows) == 10
    assert [row for row in rows if row not in out.splitlines()] == []
    # the safe recipe's budget is all warm start: the run says so and still evaluates its model
    assert "ends within the DAgger warm start" in out and "No evaluation was due during training" in out
    assert (tmp_path / "logs" / "ma2c" / "sb3_marl-LaneChange-density1-v0_2" / "best_model.zip").is_file()
    assert (tmp_path / "logs" / "ma2c" / "sb3_marl-LaneChange-density1-v0_1" / "evaluation.json").is_file()
    assert (sorted((REPO / "logs").rglob("*")) if (REPO / "logs").exists() else []) == checkout_logs


def test_the_hyperparameter_search_section_runs_verbatim(tmp_path):
    """Two invocations share one study (5 trials), then the best entry trains, all as written."""
    import optuna

    search = commands("command-line.md", "Hyperparameter search (`-optimize`)")
    assert len(search) == 3
    executable = Path(sys.executable).parent / "sb3-marl"
    for line in search:
        argv = shlex.split(line)
        completed = subprocess.run([str(executable), *argv[1:]], cwd=tmp_path, capture_output=True, text=True, timeout=600)
        assert completed.returncode == 0, f"{line}\n{completed.stdout[-2000:]}\n{completed.stderr[-2000:]}"
    backend = optuna.storages.journal.JournalFileBackend(str(tmp_path / "logs/ma2c-search.log"))
    storage = optuna.storages.JournalStorage(backend)
    study = optuna.load_study(study_name="ma2c-density1", storage=storage)
    assert len(study.trials) == 5 and study.trials[0].user_attrs["shipped_config"]
    assert (tmp_path / "logs/ma2c/sb3_marl-LaneChange-density1-v0_1/sb3_marl-LaneChange-density1-v0.zip").is_file()


def test_the_quick_start_table_is_the_committed_run():
    """Every row of the README's Quick start table is a row of results/quick-start/evaluation.md or
    evaluation_safe.md (the main job as run on the development VM; every row is also the test
    suite's own run's, :func:`test_the_quick_start_main_job_runs_verbatim`)."""
    rows = [line for line in section("README.md", "Quick start").splitlines() if line.startswith("| ")]
    committed = [
        line
        for name in ("evaluation.md", "evaluation_safe.md")
        for line in (REPO / "results" / "quick-start" / name).read_text().splitlines()
    ]
    assert len(rows) == 11 and all(row in committed for row in rows), rows  # the header and 10 rows


def test_the_trained_agents_section_runs_verbatim(tmp_path):
    """The listing and the safe agent's video, as written, from an unrelated folder: the video lands
    where the section says, with the frames it says."""
    lines = commands("README.md", "Trained agents")
    assert len(lines) == 2 and "--trained safe" in lines[1]
    executable = Path(sys.executable).parent / "sb3-marl"
    outputs = []
    for line in lines:
        completed = subprocess.run(
            [str(executable), *shlex.split(line)[1:]], cwd=tmp_path, capture_output=True, text=True, timeout=600
        )
        assert completed.returncode == 0, f"{line}\n{completed.stdout[-2000:]}\n{completed.stderr[-2000:]}"
        outputs.append(completed.stdout)
    assert "| safe (rule-prior-agreement-0.5) | ma2c | sb3_marl/LaneChange-density3-v0 | 3 |" in outputs[0]
    video = (
        tmp_path
        / "logs/trained-agents/ma2c_density3_rule-prior-agreement-0.5_seed0/videos/sb3_marl-LaneChange-density3-v0.mp4"
    )
    assert video.stat().st_size > 0 and ", 200 frames at 5 fps" in outputs[1]


@pytest.mark.parametrize(
    "page, title",
    [
        ("README.md", "Quick start"),
        ("command-line.md", "Command line"),
        ("command-line.md", "Hyperparameter search (`-optimize`)"),
    ],
)
def test_sections_have_commands(page, title):
    assert commands(page, title) and read(page)
