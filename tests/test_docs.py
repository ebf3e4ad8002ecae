"""The documentation site: it builds in strict mode (a broken link, anchor, reference or snippet
fails), and every code block a user would run, in the README and in the docs, is run by a test."""

import re
import subprocess
import sys
from pathlib import Path

import pytest
from documents import DOCS, REPO, code, code_blocks, headings, read

#: (page, heading) of every bash / python block -> the test that runs it, or why none does.
RUN_BY = {
    ("README.md", "Install"): "not run: installs from the registries; tests/test_packaging.py installs the built wheel",
    ("README.md", "Quick start"): "tests/test_readme.py::test_the_quick_start_main_job_runs_verbatim",
    ("README.md", "Example"): "tests/test_docs.py::test_the_readme_example_runs_verbatim",
    ("scenario.md", "The scenario"): "tests/test_docs.py::test_the_scenario_example_runs_verbatim",
    ("merge.md", "The on-ramp merge"): "tests/test_docs.py::test_the_merge_example_runs_verbatim",
    ("parameter-sharing.md", "Parameter sharing: every AV is a slot of one SB3 VecEnv"): (
        "tests/test_docs.py::test_the_parameter_sharing_example_runs_verbatim"
    ),
    ("parameter-sharing.md", "PettingZoo: the scenario as a ParallelEnv"): (
        "tests/envs/test_parallel.py::test_the_docs_pettingzoo_example_runs_verbatim"
    ),
    ("marl-libraries.md", "TorchRL"): (
        "tests/integrations/test_marl_libraries.py::test_the_torchrl_example_passes_check_env_specs_and_never_takes_a_masked_action"
    ),
    (
        "marl-libraries.md",
        "RLlib",
    ): "tests/integrations/test_marl_libraries.py::test_the_rllib_example_trains_two_iterations_of_shared_masked_ppo",
    (
        "marl-libraries.md",
        "BenchMARL",
    ): "tests/integrations/test_marl_libraries.py::test_the_benchmarl_example_runs_two_iterations_of_mappo",
    ("learners.md", "ACKTR"): "tests/learners/test_acktr.py::test_the_docs_example_solves_cartpole",
    ("traffic.md", "Traffic impact"): "tests/test_traffic.py::test_the_docs_command_runs_verbatim",
    ("traffic.md", "Sweeps"): "not run: minutes of evaluation; tests/benchmark/test_sweeps.py runs both sweeps small",
    ("README.md", "Trained agents"): "tests/test_readme.py::test_the_trained_agents_section_runs_verbatim",
    ("command-line.md", "Command line"): "tests/test_readme.py::test_the_command_line_section_runs_verbatim",
    ("command-line.md", "Hyperparameter search (`-optimize`)"): (
        "tests/test_readme.py::test_the_hyperparameter_search_section_runs_verbatim"
    ),
    ("hub.md", "The Hugging Face Hub"): "not run: uploads need a Hub account; tests/hub/ pushes to an in-memory Hub",
    ("benchmark.md", "Reproducing the paper: the benchmark grid on Ray Tune"): (
        "not run: hours of training; tests/benchmark/ runs tiny grids, tests/test_results.py the report"
    ),
}


def runnable_blocks() -> dict[tuple[str, str], int]:
    """(page, heading) -> number of bash / python blocks under it, over the README and every docs page."""
    found: dict[tuple[str, str], int] = {}
    for page in ["README.md", *sorted(p.name for p in DOCS.glob("*.md"))]:
        text = read(page)
        marks = headings(text)
        ends = [mark[0] for mark in marks[1:]] + [len(text)]
        for (_, start, _, title), end in zip(marks, ends[: len(marks)], strict=True):
            if count := len(code_blocks(text[start:end], "bash")) + len(code_blocks(text[start:end], "python")):
                found[page, title] = count
    return found


def test_every_runnable_block_is_run_by_a_named_test():
    blocks = runnable_blocks()
    assert set(blocks) == set(RUN_BY), "a bash or python block without a test, or a test without its block"
    for where, test in RUN_BY.items():
        assert blocks[where] == 1, f"{where}: one block per section, so the test runs all of it"
        if test.startswith("not run: "):
            continue
        path, name = test.split("::")
        assert f"def {name}(" in (REPO / path).read_text(), test


def test_the_docs_build_in_strict_mode(tmp_path):
    mkdocs = Path(sys.executable).parent / "mkdocs"
    built = subprocess.run(
        [str(mkdocs), "build", "--strict", "--site-dir", str(tmp_path / "site")],
        cwd=REPO,
        capture_output=True,
        text=True,
        env={"NO_MKDOCS_2_WARNING": "1", "PATH": str(Path(sys.executable).parent)},
        timeout=300,
    )
    assert built.returncode == 0, built.stdout + built.stderr
    api = (tmp_path / "site" / "api" / "index.html").read_text()
    assert 'id="sb3_marl.envs.lane_change_env.LaneChangeEnv"' in api  # the reference is generated
    index = (tmp_path / "site" / "index.html").read_text()
    assert "RUN_LOGS=elsewhere" in index  # the README's quick start, included
    # the figures where the pages discuss them: each page's <img> and the PNG it points to, in the site
    shown = {
        "index.html": "results/cooperative_lane_change.png",
        "benchmark/index.html": "../results/learning_curves_baselines.png",
        "command-line/index.html": "../results/video_frame.png",
        "merge/index.html": "../results/learning_curves_merge.png",
        "safety/index.html": "../results/learning_curves_rule-prior.png",
        "speed/index.html": "../results/speed/traffic_scaling.png",
    }
    for page, figure in shown.items():
        html = tmp_path / "site" / page
        assert f'src="{figure}"' in html.read_text(), page
        assert (html.parent / figure).resolve().stat().st_size > 10_000, figure


def test_the_readme_example_runs_verbatim(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    exec(compile(code("README.md", "Example"), "README.md", "exec"), namespace)
    assert (tmp_path / "ma2c_density1.zip").is_file()
    assert namespace["model"].num_timesteps >= 20_000 and namespace["done"]


def test_the_scenario_example_runs_verbatim():
    namespace: dict = {}
    exec(compile(code("scenario.md", "The scenario"), "scenario.md", "exec"), namespace)
    assert namespace["obs"].shape == (2, 5, 5) and len(namespace["info"]["rewards"]) == 2


def test_the_merge_example_runs_verbatim(capsys):
    namespace: dict = {}
    exec(compile(code("merge.md", "The on-ramp merge"), "merge.md", "exec"), namespace)
    assert namespace["obs"].shape == (4, 5, 5) and namespace["done"]
    assert namespace["on_ramp"].sum() == 2 and "ramp AVs merged" in capsys.readouterr().out


@pytest.mark.filterwarnings("ignore::UserWarning")
def test_the_parameter_sharing_example_runs_verbatim():
    namespace: dict = {}
    exec(
        compile(code("parameter-sharing.md", "Parameter sharing: every AV is a slot of one SB3 VecEnv"), "docs", "exec"),
        namespace,
    )
    assert namespace["venv"].num_envs == 6 and namespace["model"].num_timesteps >= 10_000


def test_numbers_come_from_committed_results():
    """Every number with two decimals in the README and the docs (code blocks aside) is one that a
    committed results file holds."""
    results = subprocess.run(["git", "ls-files", "results"], cwd=REPO, capture_output=True, text=True, check=True)
    corpus = "".join(
        (REPO / name).read_text(errors="replace")
        for name in results.stdout.split()
        if name.endswith((".md", ".json", ".txt", ".csv", ".yml"))
    )
    unsourced = []
    for page in ["README.md", *sorted(p.name for p in DOCS.glob("*.md"))]:
        prose = re.sub(r"```.*?```", "", read(page), flags=re.S)
        unsourced += [f"{page}: {n}" for n in re.findall(r"(?<![\w.])\d+\.\d\d(?!\d)", prose) if n not in corpus]
    assert not unsourced, unsourced
