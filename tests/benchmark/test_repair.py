"""A grid checks what it calls finished and repairs a damaged trial (issue 76, item 1).

Trials run in this process through :func:`run_trial` (Ray Tune's function trainable, without Ray:
no checkpoint to restore, reports dropped); one test runs the launcher on a local Ray."""

from __future__ import annotations

import json
import re
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

from sb3_marl.benchmark import make_grid
from sb3_marl.benchmark.grid import TrialSpec
from sb3_marl.benchmark.repair import repair_trial, restore_checkpoint, trial_damage
from sb3_marl.benchmark.report import write_report
from sb3_marl.benchmark.runner import SETTINGS_FILE, grid_status
from sb3_marl.benchmark.statistics import load_trials
from sb3_marl.benchmark.trial import run_trial
from sb3_marl.cli import main

#: The reward grid's default MA2C trial on density 1 at 600 AV-steps (300 env steps), evaluated every episode.
SPEC = make_grid("reward", (1,), 1)[0]
SETTINGS = {"budget": 0.0003, "eval_every_episodes": 1, "eval_episodes": 1}
RUN = "ma2c/sb3_marl-LaneChange-density1-v0_1"
FILES = {
    "result.json": "result.json",
    "trial.json": "trial.json",
    "evaluations": f"{RUN}/evaluations.npz",
    "model": f"{RUN}/sb3_marl-LaneChange-density1-v0.zip",
}
STATUS = ["benchmark", "status", "--grid", "reward", "--seeds", "1", "--densities", "1"]


def run(grid: Path, spec: TrialSpec = SPEC) -> None:
    """Run (or continue) ``spec``'s trial in ``grid`` in this process."""
    with warnings.catch_warnings():  # Ray's: get_checkpoint and report called outside a Tuner
        warnings.simplefilter("ignore", UserWarning)
        run_trial({"spec": spec.to_dict(), "log_folder": str(grid), "storage": None, **SETTINGS})


@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> Path:
    grid = tmp_path_factory.mktemp("grid")
    (grid / SETTINGS_FILE).write_text(json.dumps(SETTINGS))
    run(grid)
    return grid


@pytest.fixture
def grid(finished, tmp_path) -> Path:
    """A copy of the finished one-trial grid, to damage."""
    return Path(shutil.copytree(finished, tmp_path / "grid"))


def damage(path: Path) -> bytes:
    """Truncate ``path`` to half its bytes; its bytes before."""
    before = path.read_bytes()
    path.write_bytes(before[: len(before) // 2])
    return before


def attempts(grid: Path) -> list[dict]:
    return json.loads((grid / "trials" / SPEC.trial_id / "trial.json").read_text())["attempts"]


def test_a_finished_trial_records_its_training_time(finished):
    (attempt,) = attempts(finished)
    result = json.loads((finished / "trials" / SPEC.trial_id / "result.json").read_text())
    assert attempt["wall_time_s"] > 0 and result["wall_time_s"] == attempt["wall_time_s"]
    assert trial_damage(finished, SPEC) == {}
    assert grid_status("reward", finished, 1, (1,))[0].state == "finished"


@pytest.mark.parametrize("name", [*FILES, "no trial.json"])
def test_status_and_the_report_name_each_damaged_file(grid, name, capsys):
    """A finished trial whose result, trial.json, evaluations or model is truncated (or whose
    trial.json is gone) is not finished: `status` names the file (exit 1), the report says that
    it left the trial out and why."""
    folder = grid / "trials" / SPEC.trial_id
    path = folder / FILES.get(name, "trial.json")
    if name == "no trial.json":
        path.unlink()
    else:
        damage(path)
    assert main([*STATUS, "-f", str(grid)]) == 1
    captured = capsys.readouterr()
    assert re.search(rf"{SPEC.trial_id} +unreadable", captured.out) and "1 with an unreadable result" in captured.out
    assert f"unreadable: {path}: " in captured.err
    problems: list[str] = []
    assert load_trials(grid, problems) == [] and str(path) in problems[0]
    with pytest.raises(FileNotFoundError, match="No evaluated benchmark trial"):
        write_report(grid, grid / "report")
    assert f"left out of the report: {SPEC.trial_id}: " in capsys.readouterr().out


@pytest.mark.parametrize("name", FILES)
def test_a_damaged_finished_trial_is_rerun_from_its_checkpoint(grid, name, capsys):
    """The launcher's repair moves the damaged file aside (and a readable result.json, superseded),
    says so in one line, and the trial runs again from its checkpoint at its budget: finished,
    every file read back, its time summed over its attempts."""
    folder = grid / "trials" / SPEC.trial_id
    before = damage(folder / FILES[name])
    line = repair_trial(grid, SPEC)
    assert line is not None and line.startswith(f"trial {SPEC.trial_id}: {FILES[name]} unreadable (")
    assert f"): moved aside to {Path(FILES[name]).name}.damaged; " in line
    assert line.endswith("; re-run from its checkpoint at 600 AV-steps")
    assert (folder / f"{FILES[name]}.damaged").read_bytes() == before[: len(before) // 2]
    assert (folder / "result.json.superseded").is_file() == (name != "result.json")
    assert repair_trial(grid, SPEC) is None  # repaired: nothing more to do
    run(grid)
    assert trial_damage(grid, SPEC) == {}
    status = grid_status("reward", grid, 1, (1,))[0]
    assert (status.state, status.timesteps) == ("finished", 600)
    tried = attempts(grid)
    assert [a["resumed_at_timesteps"] for a in tried] == ([600] if name == "trial.json" else [0, 600])
    total = round(sum(a["wall_time_s"] for a in tried), 1)
    assert status.wall_time_s == total == json.loads((folder / "result.json").read_text())["wall_time_s"]
    timesteps = np.load(folder / FILES["evaluations"])["timesteps"]
    assert timesteps[-1] == 600 and np.all(np.diff(timesteps) > 0)


def test_a_damaged_checkpoint_does_not_fail_the_trial(grid, capsys):
    """An unfinished trial whose checkpoint's model is truncated (a kill mid-trial, then damage):
    the trial moves the checkpoint aside and runs from the start instead of failing every retry."""
    folder = grid / "trials" / SPEC.trial_id
    (folder / "result.json").unlink()
    damage(folder / "checkpoint" / "model.zip")
    status = grid_status("reward", grid, 1, (1,))[0]
    assert status.state == "unreadable" and str(folder / "checkpoint" / "model.zip") in status.problems[0]
    run(grid)  # as Ray (re)starts it, without the launcher's repair
    assert "checkpoint/model.zip unreadable (" in capsys.readouterr().out
    assert (folder / "checkpoint.damaged" / "model.zip").is_file() and trial_damage(grid, SPEC) == {}
    assert [a["resumed_at_timesteps"] for a in attempts(grid)] == [0, 0]


def test_benchmark_evaluate_names_a_damaged_trial_and_leaves_it(grid, capsys):
    """`benchmark evaluate` re-evaluates only trials that read back whole: a damaged one is named
    (exit 1), its files untouched, for the grid's next run to repair."""
    folder = grid / "trials" / SPEC.trial_id
    damage(folder / FILES["evaluations"])
    result = (folder / "result.json").read_bytes()
    assert main(["benchmark", "evaluate", "-f", str(grid)]) == 1
    err = capsys.readouterr().err
    assert f"1 trial(s) with damaged files not re-evaluated ({SPEC.trial_id}: {folder / FILES['evaluations']}: " in err
    assert (folder / "result.json").read_bytes() == result


def test_a_killed_attempts_half_written_checkpoint_is_swept(grid):
    """A kill while a checkpoint was staged leaves ``.checkpoint.partial-<pid>/`` (a model's size);
    the next attempt's first checkpoint removes it."""
    folder = grid / "trials" / SPEC.trial_id
    (folder / "result.json").unlink()
    staged = folder / ".checkpoint.partial-4194304"
    shutil.copytree(folder / "checkpoint", staged)
    damage(staged / "model.zip")
    run(grid)
    assert trial_damage(grid, SPEC) == {} and not list(folder.glob(".checkpoint.partial-*"))


def test_a_damaged_checkpoint_gives_way_to_an_older_one_that_loads(grid):
    """The launcher's repair of a damaged checkpoint: the newest of Ray's copies that loads, else
    the start; the previous checkpoint a kill left between two renames comes before those."""
    folder = grid / "trials" / SPEC.trial_id
    (folder / "result.json").unlink()
    copy = grid / "ray" / "reward-1" / SPEC.trial_id / "checkpoint_000003"
    shutil.copytree(folder / "checkpoint", copy)
    damage(folder / "checkpoint" / "evaluations.npz")
    line = repair_trial(grid, SPEC)
    assert line is not None and line.startswith(f"trial {SPEC.trial_id}: checkpoint/evaluations.npz unreadable (")
    assert line.endswith(
        "checkpoint/ moved aside to checkpoint.damaged/; re-run from Ray's copy of its checkpoint (reward-1) at 600 AV-steps"
    )
    status = grid_status("reward", grid, 1, (1,))[0]
    assert (status.state, status.timesteps, status.wall_time_s) == ("unfinished", 600, attempts(grid)[0]["wall_time_s"])

    damage(folder / "checkpoint" / "model.zip")
    shutil.copytree(copy, folder / ".checkpoint.previous")
    damage(copy / "state.json")
    assert restore_checkpoint(folder, [copy]).plan() == "re-run from its checkpoint at 600 AV-steps"
    assert not (folder / ".checkpoint.previous").exists() and (folder / "checkpoint.damaged-2").is_dir()
    damage(folder / "checkpoint" / "state.json")
    restored = restore_checkpoint(folder, [copy])
    assert restored.plan() == "re-run from the start" and not (folder / "checkpoint").exists()
    assert "checkpoint/state.json unreadable (" in restored.damaged[0]


def test_the_launcher_repairs_a_grid_on_ray(tmp_path, capsys):
    """The red-team's grid of two finished trials, one's result.json then truncated, the other's
    result lost and its checkpoint damaged: the same command re-runs both, saying how in one line each."""
    ray = pytest.importorskip("ray")
    from sb3_marl.benchmark.runner import run_benchmark

    grid = make_grid("reward", (1,), 1)
    default, global_reward = (tmp_path / "trials" / spec.trial_id for spec in grid)
    (tmp_path / SETTINGS_FILE).write_text(json.dumps(SETTINGS))
    for spec in grid:  # the grid's first run, without Ray
        run(tmp_path, spec)
    damage(default / "result.json")
    (global_reward / "result.json").unlink()
    damage(global_reward / "checkpoint" / "model.zip")
    ray.init(address="local", num_cpus=2, include_dashboard=False, configure_logging=False, log_to_driver=False)
    try:
        outcome = run_benchmark("reward", tmp_path, 0.0003, 1, (1,), 1, 1, max_concurrent=1, verbose=0)
    finally:
        ray.shutdown()
    assert sorted(outcome.completed) == [default.name, global_reward.name] and not outcome.failed
    out = capsys.readouterr().out
    assert outcome.repaired[default.name] in out and outcome.repaired[global_reward.name] in out
    assert outcome.repaired[default.name].endswith("re-run from its checkpoint at 600 AV-steps")
    assert outcome.repaired[global_reward.name].endswith("re-run from the start")
    assert main([*STATUS, "-f", str(tmp_path)]) == 0


def test_a_storage_grid_reruns_a_trial_damaged_in_the_storage(finished, tmp_path):
    """A storage grid's finished trial whose evaluations.npz was truncated in the storage: the
    launcher does not count it finished; the trial runs again on Ray and its files read back."""
    ray = pytest.importorskip("ray")
    from sb3_marl.benchmark.runner import run_benchmark
    from sb3_marl.benchmark.storage import GridStorage

    uri = f"file://{tmp_path / 'storage'}"
    GridStorage(uri).upload_trial(finished / "trials" / SPEC.trial_id)
    stored = tmp_path / "storage" / "trials" / SPEC.trial_id / FILES["evaluations"]
    damage(stored)
    ray.init(address="local", num_cpus=2, include_dashboard=False, configure_logging=False, log_to_driver=False)
    try:
        launcher = tmp_path / "launcher"
        outcome = run_benchmark("reward", launcher, 0.0003, 1, (1,), 1, 1, max_concurrent=1, verbose=0, storage=uri)
    finally:
        ray.shutdown()
    assert SPEC.trial_id in outcome.completed and not outcome.skipped and not outcome.failed
    assert np.load(stored)["timesteps"][-1] == 600
