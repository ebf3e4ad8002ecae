"""Every reader of a file kind, fuzzed with random and mutated valid files (Hypothesis): each
file is read or refused with a ValueError naming it; no other exception, no allocation beyond the
readers' bounds (a 10 MB address-space margin is not enough to matter; the bounds are the
readers' own: see sb3_marl/common/files.py and sb3_marl/algos/common/loading.py)."""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sb3_marl.algos.common.loading import read_model_data
from sb3_marl.benchmark.grid import load_experiments, load_variants
from sb3_marl.benchmark.runner import SETTINGS_FILE, grid_status
from sb3_marl.benchmark.statistics import curve_summaries, load_trials
from sb3_marl.common.files import read_evaluations, read_json_object, read_run_yaml
from sb3_marl.runs.hyperparams import load_hyperparams

REPO = Path(__file__).resolve().parents[1]
TRIAL = REPO / "results" / "paper-grid" / "trials" / "ma2c_density1_default_seed0"
FUZZ = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])

#: JSON-like values of any shape: the values a hostile or careless edit puts in a file.
JSON = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=8),
    lambda children: st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=8), children, max_size=4),
    max_leaves=12,
)


def _mutate(data: bytes, edits: list[tuple[int, int]]) -> bytes:
    """``data`` with bytes overwritten at the given (position, value) pairs."""
    mutable = bytearray(data)
    for position, value in edits:
        if mutable:
            mutable[position % len(mutable)] = value
    return bytes(mutable)


EDITS = st.lists(st.tuples(st.integers(0, 2**20), st.integers(0, 255)), max_size=8)


def _refused_or_read(read, path: Path) -> None:
    try:
        read(path)
    except ValueError as error:
        assert str(path) in str(error) or path.name in str(error), error


@FUZZ
@given(text=st.text(max_size=300))
def test_yaml_readers_read_or_name_the_file(tmp_path_factory, text):
    path = tmp_path_factory.mktemp("yaml") / "config.yml"
    path.write_text(text)
    for read in (read_run_yaml, load_variants, lambda p: load_hyperparams("ma2c", "sb3_marl/LaneChange-density1-v0", p)):
        _refused_or_read(read, path)
    try:
        load_experiments(path, {"default": {}})
    except ValueError as error:
        assert str(path) in str(error)


@FUZZ
@given(value=JSON, raw=st.binary(max_size=64))
def test_json_reader_reads_or_names_the_file(tmp_path_factory, value, raw):
    folder = tmp_path_factory.mktemp("json")
    for name, data in (("a.json", json.dumps(value).encode()), ("b.json", raw)):
        (folder / name).write_bytes(data)
        _refused_or_read(read_json_object, folder / name)


@FUZZ
@given(edits=EDITS, shape=st.lists(st.integers(0, 2**40), min_size=1, max_size=3))
def test_npz_readers_read_or_name_the_file(tmp_path_factory, edits, shape):
    folder = tmp_path_factory.mktemp("npz")
    valid = io.BytesIO()
    np.savez(valid, timesteps=np.arange(3), results=np.zeros((3, 2)), ep_lengths=np.ones((3, 2)))
    (folder / "mutated.npz").write_bytes(_mutate(valid.getvalue(), edits))
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False, "shape": tuple(shape)})
    with zipfile.ZipFile(folder / "claims.npz", "w") as archive:
        archive.writestr("results.npy", header.getvalue() + bytes(16))
    for name in ("mutated.npz", "claims.npz"):
        _refused_or_read(read_evaluations, folder / name)


@FUZZ
@given(edits=EDITS, data=JSON)
def test_model_zip_data_reads_or_names_the_file(tmp_path_factory, edits, data):
    folder = tmp_path_factory.mktemp("zip")
    (source,) = (TRIAL / "ma2c").glob("*_1/*.zip")
    (folder / "mutated.zip").write_bytes(_mutate(source.read_bytes(), edits))
    with zipfile.ZipFile(source) as old, zipfile.ZipFile(folder / "edited.zip", "w") as new:
        for member in old.infolist():
            new.writestr(member.filename, json.dumps(data) if member.filename == "data" else old.read(member))
    for name in ("mutated.zip", "edited.zip"):
        _refused_or_read(read_model_data, folder / name)


#: Edits of a grid's files: known keys given any value, nested one level where the readers look.
RESULT_KEYS = ["num_timesteps", "wall_time_s", "final_evaluation", "paper_evaluation", "trial", "returns"]
FIELD_EDITS = st.dictionaries(st.sampled_from(RESULT_KEYS), JSON, max_size=3)
TRIAL_EDITS = st.dictionaries(st.sampled_from(["algo", "density", "variant", "seed", "extra"]), JSON, max_size=3)
EVALUATION_EDITS = st.dictionaries(st.sampled_from(["return_mean", "returns", "collision_rate", "supervisor_off"]), JSON)


@FUZZ
@given(result=FIELD_EDITS, trial=TRIAL_EDITS, evaluation=EVALUATION_EDITS, budget=st.just(1.0) | JSON, whole=st.none() | JSON)
def test_a_grid_of_edited_files_is_read_or_named_trial_by_trial(tmp_path_factory, result, trial, evaluation, budget, whole):
    """An edited trial.json / result.json / benchmark.json: `status` and the report's reader list the
    trial as unreadable or refuse the folder with a message naming the file; nothing else is raised."""
    grid = tmp_path_factory.mktemp("grid")
    folder = grid / "trials" / TRIAL.name
    folder.mkdir(parents=True)
    original = json.loads((TRIAL / "result.json").read_text())
    edited = {**original, **result}
    edited["trial"] = {**original["trial"], **trial}
    edited["paper_evaluation"] = {**original["paper_evaluation"], **evaluation}
    (folder / "result.json").write_text(json.dumps(edited if whole is None else whole))
    (folder / "trial.json").write_text(json.dumps({"trial": edited["trial"]}))
    (grid / SETTINGS_FILE).write_text(json.dumps({"budget": budget}))
    problems: list[str] = []
    trials = load_trials(grid, problems)
    curve_summaries(trials)  # the report's statistics of what was read
    try:
        statuses = grid_status("baselines", grid, 1, (1,))
    except ValueError as error:
        assert SETTINGS_FILE in str(error)
        return
    for status in statuses:
        assert status.state in ("finished", "unfinished", "not started", "unreadable")
        assert isinstance(status.timesteps, int)
        assert status.return_mean is None or isinstance(status.return_mean, float)


@pytest.mark.parametrize("name", ["config.yml", "args.yml"])
def test_the_committed_run_files_still_read(name):
    (path,) = TRIAL.glob(f"ma2c/*_1/*/{name}")
    assert read_run_yaml(path)


@pytest.mark.parametrize(
    "edit, message",
    [
        ({"num_timesteps": "abc"}, "'num_timesteps' is 'abc', expected an integer"),
        ({"paper_evaluation": {"return_mean": "high"}}, "summary values and 'returns' must be numbers"),
        ({"paper_evaluation": {"returns": list(range(200_000))}}, "summary values and 'returns' must be numbers"),
    ],
)
def test_status_and_report_name_a_result_with_wrong_types(tmp_path, capsys, edit, message):
    """The red-team's edits of a result.json: `status` marks the trial unreadable naming the file
    and the field, and the report's reader leaves it out with the same reason."""
    import shutil

    from sb3_marl.cli import main

    grid = tmp_path / "grid"
    folder = grid / "trials" / TRIAL.name
    shutil.copytree(TRIAL, folder)
    result = json.loads((TRIAL / "result.json").read_text())
    for key, value in edit.items():
        result[key] = {**result[key], **value} if isinstance(value, dict) else value
    (folder / "result.json").write_text(json.dumps(result))
    (grid / SETTINGS_FILE).write_text(json.dumps({"budget": 1.0}))
    argv = ["benchmark", "status", "--grid", "baselines", "--seeds", "1", "--densities", "1", "-f", str(grid)]
    assert main(argv) == 1  # an unreadable trial: status says so and exits 1
    captured = capsys.readouterr()
    assert "1 with an unreadable result" in captured.out
    assert f"{folder / 'result.json'}: ValueError: " in captured.err and message in captured.err
    problems: list[str] = []
    assert load_trials(grid, problems) == [] and message in problems[0]


@pytest.mark.parametrize(
    "arrays",
    [
        {"timesteps": np.arange(3), "results": np.zeros(3)},  # 1-D results
        {"timesteps": np.array(["a", "b", "c"]), "results": np.zeros((3, 2))},  # string timesteps
        {"timesteps": np.arange(2), "results": np.zeros((3, 2))},  # lengths that disagree
    ],
)
def test_the_report_leaves_out_a_trial_whose_evaluations_have_the_wrong_shape(tmp_path, arrays):
    import shutil

    folder = tmp_path / "grid" / "trials" / TRIAL.name
    shutil.copytree(TRIAL, folder)
    (npz,) = folder.glob("ma2c/*_1/evaluations.npz")
    np.savez(npz, **arrays)
    problems: list[str] = []
    assert load_trials(tmp_path / "grid", problems) == []
    assert str(npz) in problems[0] and "expected numeric 'timesteps'" in problems[0]
