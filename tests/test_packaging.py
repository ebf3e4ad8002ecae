"""The package as a user installs it: the wheel and the sdist build (the sdist without the tests,
which need files of a clone), and the wheel, installed into a fresh virtual environment, runs from
an unrelated folder (the test environment's packages stand in for the dependencies, so nothing is
downloaded)."""

import re
import subprocess
import sys
import sysconfig
import tarfile
from importlib.metadata import distribution
from pathlib import Path

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

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
    assert any(name.endswith("/LICENSE") for name in names)
    assert any(name.endswith("/sb3_marl/cli/__init__.py") for name in names)
    assert any(name.endswith("/sb3_marl_launcher.py") for name in names)  # the console script's entry point
    # no tests: they read results/ and other files of a clone, which the sdist does not ship
    assert not [name for name in names if "/tests/" in name or "/results/" in name or name.endswith("/pytest.ini")]

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
        [python, "-c", "import sb3_marl, sb3_marl_launcher, zoo_configs, sb3_marl.benchmark.grid; print(sb3_marl.__file__)"],
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


def requirement_closure(name: str, extras: frozenset[str] = frozenset()) -> set[str]:
    """The distributions pip installs for ``name[extras]``: its requirements and theirs, each
    with the extras asked of it, as the installed distributions' metadata declares them."""
    seen: dict[str, frozenset[str]] = {}
    todo = [(name, extras)]
    while todo:
        name, extras = todo.pop()
        key = canonicalize_name(name)
        if key in seen and extras <= seen[key]:
            continue
        seen[key] = seen.get(key, frozenset()) | extras
        for line in distribution(name).requires or []:
            requirement = Requirement(line)
            marker = requirement.marker
            if marker is None or any(marker.evaluate({"extra": extra}) for extra in ("", *seen[key])):
                todo.append((requirement.name, frozenset(requirement.extras)))
    return set(seen)


def test_the_installs_hold_the_packages_the_readme_counts():
    """`make run` installs the runtime only and `make test` adds the dev extra: each closure of
    requirements, plus pip, has the README's package count, and the runtime holds no dev tool."""
    counts = re.search(
        r"runtime only \((\d+) packages.*?adds the `dev` extra \((\d+) packages", (ROOT / "README.md").read_text(), re.S
    )
    assert counts is not None
    runtime, dev = requirement_closure("sb3-marl"), requirement_closure("sb3-marl", frozenset({"dev"}))
    assert (len(runtime) + 1, len(dev) + 1) == (int(counts.group(1)), int(counts.group(2)))
    assert runtime < dev and not runtime & {"pytest", "ray", "mypy", "ruff", "mkdocs", "torchrl", "hypothesis"}
