"""The grid's variants and experiments are data (zoo_configs/grids/): read, checked with a message
naming the file and the entry, and each curve's overrides valid for its learner; the report's
output folder holds only what it wrote."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from sb3_marl.benchmark.grid import EXPERIMENTS, GRID_DIR, load_experiments, load_variants, make_grid
from sb3_marl.runs.hyperparams import load_hyperparams, merge_hyperparams, validate_hyperparams


def test_every_curve_of_every_experiment_validates_for_its_learner():
    for spec in {(s.algo, s.variant): s for grid in EXPERIMENTS for s in make_grid(grid, densities=(3,), seeds=1)}.values():
        hyperparams = merge_hyperparams(load_hyperparams(spec.algo, spec.env_id), spec.hyperparams)
        validate_hyperparams(spec.algo, hyperparams, spec.env_id)


def test_a_variant_extends_another_and_a_user_adds_an_experiment(tmp_path):
    variants = tmp_path / "variants.yml"
    variants.write_text(
        (GRID_DIR / "variants.yml").read_text() + "\nmy-ablation:\n  extends: rule-prior\n  hyperparams: {ent_coef: 0.02}\n"
    )
    found, merge, _ = load_variants(variants)
    assert found["my-ablation"] == {**found["rule-prior"], "ent_coef": 0.02}
    assert "my-ablation" not in merge and "merge-mobil-safety" in merge
    experiments = tmp_path / "experiments.yml"
    experiments.write_text("experiments:\n  mine:\n    MA2C, mine: [ma2c, my-ablation]\ngrids: {}\n")
    _, grids = load_experiments(experiments, found)
    assert grids == {"mine": ("mine",)}


def _variants(path):
    return load_variants(path)


def _experiments(path):
    return load_experiments(path, {"default": {}})


@pytest.mark.parametrize(
    "read, text, message",
    [
        (_variants, "a: {hyperparams: 3}", r"variant 'a', hyperparams: expected a mapping"),
        (_variants, "a: {extends: b}", r"variant 'a': extends 'b' is not a variant defined above it"),
        (_variants, "a: {scenario: moon}", r"variant 'a', scenario='moon': expected one of \['lane-change', 'merge'\]"),
        (_variants, "a: {curriculum: a}", r"variant 'a': curriculum 'a' is not a variant defined above it"),
        (_variants, "a: {hyperparam: {}}", r"variant 'a': unknown keys \['hyperparam'\]"),
        (_variants, "- a", r"must be a mapping"),
        (_variants, "a: !!python/object/apply:os.system [echo]", r"not a plain-data YAML file"),
        (_experiments, "experiments: {x: {c: [ma2c, nope]}}\ngrids: {}", r"variant='nope': expected one of \['default'\]"),
        (_experiments, "experiments: {x: {c: [sac, default]}}\ngrids: {}", r"curve 'c', learner='sac'"),
        (_experiments, "experiments: {x: {c: ma2c}}\ngrids: {}", r"curve 'c': expected \[learner, variant\]"),
        (_experiments, "experiments: {x: {c: [ma2c, default]}}\ngrids: {g: [y]}", r"grid 'g', experiment='y'"),
        (_experiments, "experiments: {}", r"expected the keys \['experiments', 'grids'\]"),
    ],
)
def test_bad_grid_files_are_refused_naming_the_file_and_entry(tmp_path, read, text, message):
    path = tmp_path / "grid.yml"
    path.write_text(text)
    with pytest.raises(ValueError, match=message) as error:
        read(path)
    assert str(path) in str(error.value)


def test_the_report_deletes_only_files_it_wrote_and_refuses_a_foreign_folder(tmp_path, capsys):
    """`benchmark report -o D`: D with files but no report manifest is refused before anything is
    written; in a report's folder, only the files of that earlier report that it does not write
    again are deleted (a user's file named like a report output stays)."""
    from sb3_marl.benchmark.report import MANIFEST, write_report
    from sb3_marl.cli import main

    grid = Path(__file__).resolve().parents[2] / "results" / "paper-grid"
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "learning_curves_mine.png").write_text("a user's figure")
    assert main(["benchmark", "report", "-f", str(grid), "-o", str(foreign)]) == 2
    assert "holds files that no report wrote" in capsys.readouterr().err
    assert [p.name for p in foreign.iterdir()] == ["learning_curves_mine.png"]
    (foreign / "report.png").write_text("x")
    assert main(["benchmark", "report", "-f", str(foreign / "report.png"), "-o", str(foreign / "report.png")]) == 2
    out = tmp_path / "report"
    out.mkdir()
    (out / MANIFEST).write_text('["learning_curves_gone.png"]')
    (out / "learning_curves_gone.png").write_text("an earlier report's")
    (out / "learning_curves_user.png").write_text("a user's")
    written = write_report(grid, out)
    assert not (out / "learning_curves_gone.png").exists() and (out / "learning_curves_user.png").exists()
    assert json.loads((out / MANIFEST).read_text()) == sorted(p.name for p in written)
    (out / MANIFEST).write_text('["../outside.txt"]')
    with pytest.raises(ValueError, match="expected a list of file names"):
        write_report(grid, out)


def test_one_launcher_per_grid_folder(tmp_path, capsys):
    """A second launcher on a grid folder another process runs is refused before Ray starts,
    naming the holder; once the holder ends, the folder is free."""
    import subprocess
    import sys
    import time

    from sb3_marl.benchmark.runner import HOLDER_FILE, grid_lock
    from sb3_marl.cli import main

    folder = tmp_path / "grid"
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys, time; from pathlib import Path; from sb3_marl.benchmark.runner import grid_lock\n"
            "with grid_lock(Path(sys.argv[1])):\n    print('held', flush=True); time.sleep(60)",
            str(folder),
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "held"
        argv = ["benchmark", "--grid", "reward", "--budget", "0.0003", "--seeds", "1", "--densities", "1", "-f", str(folder)]
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert "is being run by another launcher (host " in err and f"pid {holder.pid}" in err and "--wait" in err
        assert (folder / HOLDER_FILE).is_file() and not (folder / "trials").exists()
    finally:
        holder.kill()
        holder.wait()
    start = time.perf_counter()
    with grid_lock(folder):  # the lock went with its process
        assert json.loads((folder / HOLDER_FILE).read_text())["pid"] != holder.pid
    assert time.perf_counter() - start < 5 and not (folder / HOLDER_FILE).exists()


def test_crafted_trial_files_are_named_and_links_out_of_the_grid_not_followed(tmp_path, capsys):
    """A trial.json naming ``../..`` as its learner, a result.json with density 9, and a trial folder
    that is a link to a folder outside the grid: each one message naming the file; nothing is read
    or written outside the grid."""
    import shutil

    from sb3_marl.benchmark.statistics import load_trials
    from sb3_marl.cli import main

    source = Path(__file__).resolve().parents[2] / "results" / "paper-grid" / "trials" / "ma2c_density1_default_seed0"
    grid = tmp_path / "grid"
    shutil.copytree(source, grid / "trials" / source.name)
    trial_json = grid / "trials" / source.name / "trial.json"
    info = json.loads(trial_json.read_text())
    trial_json.write_text(json.dumps({**info, "trial": {**info["trial"], "algo": "../../.."}}))
    problems: list[str] = []
    assert load_trials(grid, problems) == [] and "Invalid algo='../../..'" in problems[0]

    # `benchmark evaluate` names a trial whose files do not read back (exit 1) and evaluates nothing of it
    assert main(["benchmark", "evaluate", "-f", str(grid)]) == 1
    err = capsys.readouterr().err
    assert f"{trial_json}: 'trial' ValueError: Invalid algo='../../..'" in err and "Traceback" not in err
    trial_json.write_text(json.dumps(info))
    result_json = grid / "trials" / source.name / "result.json"
    result = json.loads(result_json.read_text())
    result_json.write_text(json.dumps({**result, "trial": {**result["trial"], "density": 9}}))
    assert main(["benchmark", "evaluate", "-f", str(grid)]) == 2
    err = capsys.readouterr().err
    assert f"{result_json}: 'trial' Invalid density=9: expected one of [1, 2, 3]" in err and "Traceback" not in err

    outside = tmp_path / "outside"
    shutil.move(str(grid / "trials" / source.name), outside)
    (grid / "trials" / source.name).symlink_to(outside, target_is_directory=True)
    before = (outside / "result.json").read_text()
    assert main(["benchmark", "evaluate", "-f", str(grid)]) == 2
    assert "outside" in capsys.readouterr().err and (outside / "result.json").read_text() == before


def test_a_failed_trial_is_reported_by_its_own_error_without_terminal_colours():
    """Ray wraps a trial's exception (e.g. a refused foreign checkpoint) in a RayTaskError whose
    text starts with coloured worker details: the launcher reports the trial's own error."""
    RayTaskError = pytest.importorskip("ray.exceptions").RayTaskError

    from sb3_marl.algos.common.loading import UnsafeModelError
    from sb3_marl.benchmark.runner import failure_reason

    cause = UnsafeModelError("model.zip: the entry 'policy_class' is pickled code sb3-marl cannot rebuild")
    wrapped = RayTaskError("\x1b[36mray::ImplicitFunc.train()\x1b[39m", "Traceback (most recent call last): ...", cause)
    for error in (wrapped, wrapped.as_instanceof_cause()):
        assert failure_reason(error) == f"UnsafeModelError: {cause}"


#: ``python -c`` of the command line after it, where no module of Ray can be imported, as where it
#: is not installed (a finder ahead of the others refuses them).
WITHOUT_RAY = """
import sys

class NoRay:
    def find_spec(self, name, path=None, target=None):
        if name == "ray" or name.startswith("ray."):
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return None

sys.meta_path.insert(0, NoRay())

from sb3_marl.cli import main

sys.exit(main(sys.argv[1:]))
"""


def test_without_ray_installed_the_command_says_how_to_install_it(tmp_path):
    """In a fresh interpreter where importing Ray fails (whether or not it is installed here), the
    benchmark command stops with the install command and starts no trial."""
    argv = ["benchmark", "--grid", "reward", "--densities", "1", "--seeds", "1", "-f", str(tmp_path)]
    completed = subprocess.run([sys.executable, "-c", WITHOUT_RAY, *argv], capture_output=True, text=True, timeout=300)
    assert completed.returncode == 1, completed.stdout[-2000:] + completed.stderr[-2000:]
    assert "pip install 'sb3-marl[ray]'" in completed.stderr
    assert not list(tmp_path.glob("trials/*"))
