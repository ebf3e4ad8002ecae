"""The package as a user installs it: the wheel and the sdist build, and the wheel, installed into a
fresh virtual environment, runs from an unrelated folder (the test environment's packages stand in
for the dependencies, so nothing is downloaded)."""

import subprocess
import sys
import sysconfig
import tarfile
from pathlib import Path

from sb3_marl import __version__

ROOT = Path(__file__).resolve().parents[1]


def test_the_wheel_installs_and_runs_from_an_unrelated_folder(tmp_path):
    dist = tmp_path / "dist"
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", str(ROOT), "--no-deps", "--no-build-isolation", "-q", "-w", str(dist)],
        check=True,
        cwd=tmp_path,
    )
    subprocess.run(
        [sys.executable, "-m", "build", "--sdist", "--no-isolation", "-o", str(dist), str(ROOT)],
        check=True,
        cwd=tmp_path,
        capture_output=True,
    )
    (wheel,) = dist.glob("sb3_marl-*.whl")
    (sdist,) = dist.glob("sb3_marl-*.tar.gz")
    with tarfile.open(sdist) as archive:
        names = archive.getnames()
    assert any(name.endswith("LICENSE") for name in names) and sum("/tests/" in name for name in names) > 20
    assert not any("/results/" in name for name in names)

    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    site = Path(
        subprocess.run(
            [str(venv / "bin" / "python"), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
            check=True,
            capture_output=True,
            text=True,
        ).stdout.strip()
    )
    # the test environment's packages as plain paths (its editable sb3-marl hook is not run from there)
    (site / "dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", str(site), str(wheel)], check=True)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    python, cli = str(venv / "bin" / "python"), [str(venv / "bin" / "python"), "-m", "sb3_marl"]
    located = subprocess.run(
        # the benchmark reads its grids from zoo_configs/grids/ (package data)
        [python, "-c", "import sb3_marl, zoo_configs, sb3_marl.benchmark.grid; print(sb3_marl.__file__)"],
        cwd=elsewhere,
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    assert located.startswith(str(site))
    version = subprocess.run([*cli, "--version"], cwd=elsewhere, check=True, capture_output=True, text=True).stdout
    assert version.strip() == f"sb3-marl {__version__}"
    for argv in (
        ["train", "-n", "240", "--eval-freq", "120", "--eval-episodes", "1", "-params", "n_steps:20"],
        ["evaluate", "--eval-episodes", "2"],
    ):
        subprocess.run([*cli, *argv, "-f", "logs"], cwd=elsewhere, check=True, capture_output=True)
    assert (elsewhere / "logs" / "ma2c" / "sb3_marl-LaneChange-density1-v0_1" / "evaluation.json").is_file()
    assert not list((site / "sb3_marl").rglob("*.nbi"))  # numba's cache is in the user's cache folder
