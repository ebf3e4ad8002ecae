"""Bad input and failures, as a new user meets them: each gets a clear message, before any work
and any folder, or (for failures during training) after the model was saved. Real runs, tiny."""

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from sb3_marl import __version__
from sb3_marl.algos.a2c import MaskableA2C
from sb3_marl.cli import main

ENV = "sb3_marl/LaneChange-density1-v0"
ENV_NAME = "sb3_marl-LaneChange-density1-v0"
TINY = ["-n", "600", "--eval-freq", "-1", "-params", "n_steps:20"]


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> Path:
    """One tiny MA2C run (id 1), trained with the default --verbose (1)."""
    folder = tmp_path_factory.mktemp("logs")
    assert main(["train", "-f", str(folder), *TINY]) == 0
    return folder


def test_default_verbosity_is_short_and_verbose_2_prints_the_logger_table(tmp_path, capsys):
    """MA2C dumps its logger every 10 updates: 1200 AV-steps of 120-step rollouts. By default the
    console has the set-up lines (copies and AV slots) and the evaluations, no logger tables."""
    argv = ["train", "-f", str(tmp_path), *TINY, "-n", "1200", "--eval-freq", "600", "--eval-episodes", "1"]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "3 scenario copies with 1, 2, 3 AVs: 6 AV slots" in out and "Using 1 environments" not in out
    assert "Eval num_timesteps=" in out and "rollout/" not in out
    assert main([*argv, "--verbose", "2"]) == 0
    out = capsys.readouterr().out
    assert "rollout/" in out and "supervisor_interventions" in out and "train/" in out


def test_version(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["--version"])
    assert exit_info.value.code == 0 and capsys.readouterr().out.strip() == f"sb3-marl {__version__}"


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["train", "-n", "0"], "argument -n/--n-timesteps: expected an integer >= 1 or -1 (the default), got '0'"),
        (["train", "-n", "-5"], "argument -n/--n-timesteps: expected an integer >= 1 or -1"),
        (["train", "--log-interval", "0"], "argument --log-interval: expected an integer >= 1 or -1"),
        (["train", "--num-threads", "0"], "argument --num-threads: expected an integer >= 1 or -1"),
        (["train", "--eval-freq", "0"], "argument --eval-freq: expected an integer >= 1 (AV-steps) or -1 (never)"),
        (["train", "--save-freq", "-3"], "argument --save-freq: expected an integer >= 1 (AV-steps) or -1 (never)"),
    ],
)
def test_bad_numbers_are_usage_errors(argv, message, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2 and message in capsys.readouterr().err


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ("n_steps:abc", "Invalid hyperparameter n_steps='abc': expected an integer >= 1"),
        ("n_steps:2.5", "Invalid hyperparameter n_steps=2.5: expected an integer >= 1"),
        ("n_steps:-3", "Invalid hyperparameter n_steps=-3: expected an integer >= 1"),
        ("learning_rate:fast", "Invalid hyperparameter learning_rate='fast': expected a finite number >= 0 (or a schedule"),
        ("gamma:0.99.", "Invalid hyperparameter gamma='0.99.': expected a finite number >= 0 and <= 1"),
        ("gamma:nan", "Invalid hyperparameter gamma=nan"),
        ("action_masking:'yes'", "Invalid action_masking='yes'"),
        ("action_masking:true", "expected true or false (True or False in a key:value on the command line)"),
        ("stored_actions:'both'", "Invalid stored_actions='both'"),
        ("env_config:dict(headway_time=inf)", "config['headway_time'] = inf: expected a finite number"),
    ],
)
def test_bad_hyperparameters_fail_before_any_folder(params, message, tmp_path, capsys):
    assert main(["train", "-f", str(tmp_path / "logs"), "-params", params]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "logs").exists()


def test_schedules_are_accepted(tmp_path):
    assert main(["train", "-f", str(tmp_path), *TINY, "--verbose", "0", "-params", "learning_rate:'lin_5e-4'"]) == 0


def test_bad_paths_and_devices_fail_before_any_folder(tmp_path, capsys):
    a_file = tmp_path / "file.txt"
    a_file.write_text("not a folder")
    broken_yaml = tmp_path / "broken.yml"
    broken_yaml.write_text("sb3_marl/LaneChange-density1-v0:\n  n_steps: [1, 2\n")
    logs = str(tmp_path / "logs")
    cases = [
        (["-f", str(a_file)], "-f/--log-folder: '" + str(a_file) + "' is a file, expected a folder"),
        (["-f", logs, "-tb", str(a_file)], "-tb/--tensorboard-log: '" + str(a_file) + "' is a file"),
        (["-f", logs, "--device", "banana"], "--device: invalid device 'banana': expected auto, cpu, cuda"),
        (["-f", logs, "-c", str(broken_yaml)], f"{broken_yaml} is not valid YAML"),
        (["-f", logs, "-c", str(tmp_path / "missing.yml")], "-c/--conf-file: "),
        (["-f", logs, "-c", "ma2c_unsafe"], "nor a shipped zoo config: one of ['ma2c', 'ma2c_safe', "),
    ]
    for argv, message in cases:
        assert main(["train", *argv]) == 2, argv
        assert message in capsys.readouterr().err
    assert not (tmp_path / "logs").exists()


def test_a_model_of_another_algorithm_is_refused(trained, tmp_path, capsys):
    model = trained / "ma2c" / f"{ENV_NAME}_1" / f"{ENV_NAME}.zip"
    assert main(["train", "--algo", "mappo", "-f", str(tmp_path), "-i", str(model)]) == 2
    assert f"{model} is a MaskableA2C model, not a mappo (MaskedPPO) model" in capsys.readouterr().err
    assert not (tmp_path / "mappo").exists()


@pytest.mark.parametrize("damage", ["truncated", "garbage"])
@pytest.mark.parametrize("command", ["evaluate", "record-video"])
def test_corrupt_models_are_usage_errors_naming_the_file(command, damage, trained, tmp_path, capsys):
    folder = tmp_path / "logs"
    shutil.copytree(trained, folder)
    model = folder / "ma2c" / f"{ENV_NAME}_1" / f"{ENV_NAME}.zip"
    data = model.read_bytes()
    model.write_bytes(data[: len(data) // 2] if damage == "truncated" else b"not a zip at all")
    assert main([command, "-f", str(folder)]) == 2
    assert f"{model} is not a readable SB3 model file" in capsys.readouterr().err


def test_evaluate_skips_a_latest_run_without_model(trained, tmp_path, capsys):
    folder = tmp_path / "logs"
    shutil.copytree(trained, folder)
    (folder / "ma2c" / f"{ENV_NAME}_2").mkdir()  # what a run killed before its first save leaves
    assert main(["evaluate", "-f", str(folder), "--eval-episodes", "1"]) == 0
    assert f"{ENV_NAME}_1/{ENV_NAME}.zip" in capsys.readouterr().out


def test_hub_flags_are_checked(trained, tmp_path, capsys):
    not_empty = tmp_path / "card"
    not_empty.mkdir()
    (not_empty / "x").write_text("x")
    cases = [
        (["load-from-hub", "--repo-id", "no slash here", "-f", str(tmp_path)], "--repo-id: invalid Hub repo id"),
        (["load-from-hub", "--repo-id", "a/b/c", "-f", str(tmp_path)], "--repo-id: invalid Hub repo id 'a/b/c'"),
        (["push-to-hub", "-orga", "bad org!", "-f", str(trained), "--dry-run", str(tmp_path / "new")], "invalid Hub repo id"),
        (["push-to-hub", "-f", str(trained)], "-orga/--organization: required to upload"),
        (
            ["push-to-hub", "-orga", "me", "-f", str(trained), "--dry-run", str(not_empty)],
            f"--dry-run: '{not_empty}' exists and is not an empty folder",
        ),
        (
            ["push-to-hub", "-orga", "me", "-f", str(trained), "--dry-run", str(not_empty / "x")],
            "exists and is not an empty folder",
        ),
    ]
    for argv, message in cases:
        assert main(argv) == 2, argv
        assert message in capsys.readouterr().err
    assert (not_empty / "x").read_text() == "x" and not (tmp_path / "new").exists()


def _grandchildren(pid: int) -> list[int]:
    """The processes two levels below ``pid`` (Linux /proc): the subproc workers, which the
    forkserver (a child, beside the resource tracker) starts."""
    children: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                stat = Path(f"/proc/{entry}/stat").read_text()
            except OSError:
                continue
            parent = int(stat.rsplit(")", 1)[1].split()[1])
            children.setdefault(parent, []).append(int(entry))
    return [grandchild for child in children.get(pid, []) for grandchild in children.get(child, [])]


def test_a_worker_dying_mid_training_saves_the_model_and_says_why(tmp_path):
    """A real failure during training (a subproc worker killed): the model is saved, then a clear error."""
    from sb3_marl.envs import av_counts

    command = [
        sys.executable,
        "-m",
        "sb3_marl",
        "train",
        "-f",
        str(tmp_path),
        "--vec-env",
        "subproc",
        "-n",
        "2000000",
        "--eval-freq",
        "-1",
        "--verbose",
        "0",
        "-params",
        "n_steps:20",
    ]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        monitor = tmp_path / "ma2c" / f"{ENV_NAME}_1" / "monitor.csv"
        deadline = time.time() + 120
        while time.time() < deadline and (not monitor.is_file() or monitor.stat().st_size < 2000):
            time.sleep(0.5)
        workers = _grandchildren(process.pid)
        # one worker per core, at most one per scenario copy (one copy per AV count of the density)
        assert len(workers) == min(len(av_counts(ENV)), os.cpu_count() or 1), workers
        os.kill(workers[-1], signal.SIGKILL)
        out, err = process.communicate(timeout=120)
    finally:
        process.kill()  # never leave a 2M-step training behind
        process.wait()
    assert process.returncode == 1, out + err
    assert "training stopped by" in err and "was saved; continue with -i" in err
    model = tmp_path / "ma2c" / f"{ENV_NAME}_1" / f"{ENV_NAME}.zip"
    assert 0 < MaskableA2C.load(model).num_timesteps < 2_000_000


def test_every_flag_has_help_and_help_shows_the_defaults(capsys):
    import argparse

    from sb3_marl.cli import build_parser

    commands = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    missing = [
        (name, action.option_strings)
        for name, parser in commands.choices.items()
        for action in parser._actions
        if action.option_strings and not action.help
    ]
    assert missing == []
    with pytest.raises(SystemExit):
        main(["baselines", "--help"])
    out = " ".join(capsys.readouterr().out.split())
    assert (
        "episode seeds start at seed + 10000, as evaluate's (default: 0)" in out
        and "(default: logs/baselines_<env>.md)" in out
    )
