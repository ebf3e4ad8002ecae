"""The packages are the architecture's layers: imports only point down, and no module imports
itself back through others (no circle); the package's top and the learners' class stacks stay small.
Module size is no rule here: a module is split where it holds two ideas (a line count was met by
joining lines)."""

from __future__ import annotations

import ast
import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: Layers from the bottom; a module may import its own layer's package and any lower layer.
#: Packages on one layer (wrappers and evaluation; benchmark and hub) do not import each other.
LAYERS: tuple[tuple[str, ...], ...] = (
    ("sb3_marl.common",),
    ("sb3_marl.sim",),
    ("sb3_marl.safety",),
    ("sb3_marl.envs",),
    ("wrappers", "sb3_marl.evaluation"),
    ("sb3_marl.algos",),
    ("sb3_marl.runs",),
    ("sb3_marl.benchmark", "sb3_marl.hub"),
    ("sb3_marl.cli",),
    ("sb3_marl.__main__",),
)
MAX_TOP_LEVEL_MODULES = 8


def _modules() -> dict[str, Path]:
    files = [*ROOT.joinpath("sb3_marl").rglob("*.py"), *ROOT.joinpath("wrappers").rglob("*.py")]
    modules = {}
    for path in files:
        parts = list(path.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        modules[".".join(parts)] = path
    return modules


MODULES = _modules()


def _package(module: str) -> str:
    """The layer package a module belongs to (the longest listed prefix)."""
    names = [name for layer in LAYERS for name in layer if module == name or module.startswith(name + ".")]
    if not names:
        raise AssertionError(f"{module} is in no layer of tests/test_architecture.py:LAYERS")
    return max(names, key=len)


def _layer(package: str) -> int:
    return next(level for level, names in enumerate(LAYERS) if package in names)


def _imports(module: str) -> set[str]:
    """Every project module ``module`` imports, anywhere in it (functions and TYPE_CHECKING too)."""
    found = set()
    is_package = MODULES[module].name == "__init__.py"
    for node in ast.walk(ast.parse(MODULES[module].read_text())):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = module.split(".")[: len(module.split(".")) - node.level + (1 if is_package else 0)]
                base = ".".join([*anchor, base] if base else anchor)
            names = [base, *(f"{base}.{alias.name}" for alias in node.names)]
        else:
            continue
        found |= {name for name in names if name in MODULES}
    return found - {module}


def test_imports_only_point_down():
    upward = []
    for module in MODULES:
        if module == "sb3_marl":  # the root package registers the scenarios' gymnasium ids
            continue
        here = _package(module)
        for imported in _imports(module):
            if imported == "sb3_marl":
                continue
            there = _package(imported)
            if there != here and _layer(there) >= _layer(here):
                upward.append(f"{module} -> {imported}")
    assert not upward, "imports that do not point down:\n" + "\n".join(sorted(upward))


def test_no_import_circle():
    graph = {module: _imports(module) - {"sb3_marl"} for module in MODULES}
    circles, done, path = [], set(), []

    def visit(module: str) -> None:
        if module in path:
            circles.append(" -> ".join([*path[path.index(module) :], module]))
            return
        if module in done:
            return
        path.append(module)
        for imported in sorted(graph[module]):
            # a package's __init__ naming its own submodules is how Python packages export
            if not imported.startswith(module + "."):
                visit(imported)
        path.pop()
        done.add(module)

    for module in sorted(graph):
        visit(module)
    assert not circles, "import circles:\n" + "\n".join(circles)


def test_few_modules_at_the_top():
    """The package's top holds its entry points, not its concepts (those live in the layers)."""
    top = [path.name for path in ROOT.joinpath("sb3_marl").glob("*.py")]
    assert len(top) <= MAX_TOP_LEVEL_MODULES, top


@pytest.mark.parametrize("name", ["ma2c", "mappo", "madqn", "maacktr", "matrpo"])
def test_a_learner_stacks_at_most_three_of_our_classes(name):
    from sb3_marl.algos import get_algo

    ours = [cls.__qualname__ for cls in get_algo(name).__mro__ if cls.__module__.startswith(("sb3_marl", "wrappers"))]
    assert len(ours) <= 3, ours


#: Folders of models committed before the rule that only named trained agents' models are
#: (results/README.md); tests re-evaluate them. No folder is added here.
EARLIER_MODEL_FOLDERS = ("results/ma2c-full-budget/logs/", "results/safety/mappo-density1/")


def test_the_repository_commits_models_only_for_the_named_trained_agents():
    """Every model zip in git is a grid trial's final model (a trained agent by name), or one of
    the earlier folders' (the repository stays light: results/README.md)."""
    tracked = subprocess.run(["git", "ls-files", "*.zip"], cwd=ROOT, capture_output=True, text=True, check=True).stdout.split()
    if not tracked:
        pytest.skip("not a git checkout")
    final_model = r"^results/paper-grid/trials/[^/]+/[a-z0-9]+/(sb3_marl-[A-Za-z]+-density\d-v0)_\d+/\1\.zip$"
    stray = [path for path in tracked if not re.match(final_model, path) and not path.startswith(EARLIER_MODEL_FOLDERS)]
    assert stray == [], f"models that are no named trained agent's (results/README.md: what is committed): {stray}"
