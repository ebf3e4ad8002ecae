"""The committed results regenerate from the committed slim logs (results/*/logs): the summary
table byte for byte, the learning-curve PNGs pixel for pixel up to antialiasing, and a committed
model re-evaluated on the first seeds of its committed evaluation gives the same episode returns
(to a relative 1e-6: float rounding may differ between machines, AVX2 or AVX-512)."""

import json
from pathlib import Path

import imageio.v2 as imageio
import numpy as np
import pytest
from documents import markdown_tables

from sb3_marl.cli import main
from sb3_marl.runs.folders import find_run

RESULTS = Path(__file__).resolve().parent.parent / "results"
LOG_FOLDERS = sorted(RESULTS.glob("*/logs"))
#: Relative tolerance of a re-evaluated return against the committed one: far above the last bits
#: another machine's rounding changes, far below what another action or reward changes.
RETURN_TOLERANCE = 1e-6
#: A regenerated PNG matches the committed one when it has the same size, at most this share of
#: its pixels differ by more than PIXEL_LEVELS (of 255) in a channel, and its mean absolute
#: difference is at most MEAN_LEVELS: room for another machine's antialiasing of text and lines,
#: none for a curve left out (one of the 12 runs of results/ma2c-full-budget's collision-rate
#: figure: 1.4 % of the pixels, mean difference 0.96).
PIXEL_LEVELS, PIXEL_SHARE, MEAN_LEVELS = 16, 0.005, 0.5


def image_difference(regenerated: Path, committed: Path) -> tuple[float, float] | None:
    """(share of pixels differing by more than :data:`PIXEL_LEVELS` in a channel, mean absolute
    difference) of two PNGs, None when their sizes differ."""
    new, old = (imageio.imread(path).astype(np.int16) for path in (regenerated, committed))
    if new.shape != old.shape:
        return None
    difference = np.abs(new - old)
    return float((difference.max(axis=-1) > PIXEL_LEVELS).mean()), float(difference.mean())


def test_there_are_committed_results():
    assert LOG_FOLDERS, "results/<study>/logs holds the slim logs of the committed results"


@pytest.mark.parametrize("logs", LOG_FOLDERS, ids=lambda p: p.parent.name)
def test_the_summary_regenerates(logs, tmp_path):
    assert main(["summary", "-f", str(logs), "-o", str(tmp_path / "summary.md")]) == 0
    text = (tmp_path / "summary.md").read_text()
    assert text == (logs.parent / "summary.md").read_text()
    episodes = {json.loads(path.read_text())["episodes"] for path in logs.glob("*/*/evaluation.json")}
    assert "| supervisor | episodes |" in text and all(f"| {n} |" in text for n in episodes)  # each row's episode count


@pytest.mark.parametrize("logs", LOG_FOLDERS, ids=lambda p: p.parent.name)
def test_the_plots_regenerate(logs, tmp_path):
    committed = sorted((logs.parent / "plots").glob("*/*.png"))
    assert committed
    for folder in sorted({png.parent for png in committed}):
        env = f"sb3_marl/LaneChange-{folder.name}-v0"
        out = tmp_path / folder.name
        assert main(["plot", "--algo", "ma2c", "--env", env, "-f", str(logs), "-o", str(out)]) == 0
        for png in folder.glob("*.png"):
            difference = image_difference(out / png.name, png)
            assert difference is not None, f"{png}: another size in pixels"
            share, mean = difference
            assert share <= PIXEL_SHARE and mean <= MEAN_LEVELS, (png, share, mean)


@pytest.mark.parametrize("logs", LOG_FOLDERS, ids=lambda p: p.parent.name)
def test_committed_models_reproduce_their_evaluation(logs):
    """Each density's first run: its model, re-evaluated on the first 3 seeds of its committed
    30-episode evaluation (same protocol, same supervisor version), gives the same returns."""
    for evaluation in sorted(logs.glob("ma2c/*_1/evaluation.json")):
        committed = json.loads(evaluation.read_text())
        run = find_run(logs, "ma2c", committed["env_id"], exp_id=1)
        run.hyperparams["env_config"] = {**run.env_config, "supervisor_version": committed["supervisor_version"]}
        model = run.load_model("cpu")
        again = run.evaluate(model, 3, committed["seeds"][0], committed["deterministic"])
        assert again["returns"] == pytest.approx(committed["returns"][:3], rel=RETURN_TOLERANCE)
        assert again["protocol"] == committed["protocol"]


PAPER_GRID = RESULTS / "paper-grid"


def test_the_paper_grid_table_regenerates():
    """results/paper_table.md is `sb3-marl benchmark report -f results/paper-grid -o results`'s
    table of the committed trials (finished trials' slim logs, unfinished trials' checkpoints)."""
    import json

    from sb3_marl.benchmark.statistics import load_trials, reference_summaries
    from sb3_marl.benchmark.tables import paper_table

    settings = json.loads((PAPER_GRID / "benchmark.json").read_text())
    assert settings == {"budget": 1.0, "eval_every_episodes": 200, "eval_episodes": 3}  # the paper's protocol
    trials = load_trials(PAPER_GRID)
    references = reference_summaries(trials, PAPER_GRID, seed=10_000)  # IDM/MOBIL etc., replayed
    assert paper_table(trials, settings, references) == (RESULTS / "paper_table.md").read_text()


@pytest.mark.parametrize("algo", ["ma2c", "madqn", "maacktr", "mappo"])
def test_committed_grid_models_reproduce_their_final_evaluation(algo):
    """Each learner's density-1 seed-0 grid model, re-evaluated on the first 3 episodes of its
    final evaluation (same seeds, sampled actions, its scenario config, the supervisor version it
    records), gives the committed returns with the supervisor and without it (to
    :data:`RETURN_TOLERANCE`), and the same protocol."""
    trial = PAPER_GRID / "trials" / f"{algo}_density1_default_seed0"
    committed = json.loads((trial / "result.json").read_text())["paper_evaluation"]
    run = find_run(trial, algo, "sb3_marl/LaneChange-density1-v0")
    run.hyperparams["env_config"] = {**run.env_config, "supervisor_version": committed["supervisor_version"]}
    again = run.evaluate(run.load_model("cpu"), 3, committed["seeds"][0])
    assert again["supervisor_version"] == committed["supervisor_version"]
    assert again["returns"] == pytest.approx(committed["returns"][:3], rel=RETURN_TOLERANCE)
    alone = committed["supervisor_off"]["returns"][:3]
    assert again["supervisor_off"]["returns"] == pytest.approx(alone, rel=RETURN_TOLERANCE)
    assert again["protocol"] == committed["protocol"]


def test_the_readmes_state_the_committed_grid_status(capsys):
    """The grid status the docs' benchmark page and results/README.md state is `sb3-marl benchmark status`
    of the committed trials."""
    import re

    assert main(["benchmark", "status", "--seeds", "3", "-f", str(PAPER_GRID)]) == 0
    finished = re.search(r": (\d+) of 81 trials finished", capsys.readouterr().out).group(1)
    readme = re.sub(r"\s+", " ", (RESULTS.parent / "docs" / "benchmark.md").read_text())
    assert f"**Status: {finished} of 81 trials finished**" in readme
    assert f"**Done: {finished} of 81 trials**" in (RESULTS / "README.md").read_text()


def _readme_table(readme: Path, header: list[str]) -> list[dict[str, str]]:
    (table,) = [t for t in markdown_tables(readme.read_text()) if list(t[0]) == header]
    return table


@pytest.fixture(scope="module")
def committed_rows() -> dict[tuple[str, int], dict[str, str]]:
    """results/paper_table.md's rows keyed by (curve or policy, density)."""
    return {
        (row.get("curve", row.get("policy")), int(row["density"])): row
        for table in markdown_tables((RESULTS / "paper_table.md").read_text())
        for row in table
    }


DENSITIES = ["density 1", "density 2", "density 3"]


def test_the_headline_tables_are_the_reports():
    """results/headline.md is the report's headline table of the committed trials, and the README's
    copy of it (between its headline markers) is that file, byte for byte."""
    from sb3_marl.benchmark.statistics import curve_summaries, load_trials, reference_summaries
    from sb3_marl.benchmark.tables import headline_table

    trials = load_trials(PAPER_GRID)
    references = reference_summaries(trials, PAPER_GRID, seed=10_000)
    headline = (RESULTS / "headline.md").read_text()
    assert headline_table(curve_summaries(trials), references) == headline
    readme = (RESULTS.parent / "README.md").read_text()
    copy = readme.split("<!-- headline:start -->\n", 1)[1].split("<!-- headline:end -->", 1)[0]
    assert copy == headline


#: results/README.md's "MA2C in detail" rows -> the cell of paper_table.md's rows they copy.
MA2C_DETAIL_ROWS = {
    "MA2C (current config): mean ± std over seeds": lambda rows, d: rows["MA2C", d]["return: mean ± std over seeds"],
    "MA2C: IQM [95 % CI]": lambda rows, d: rows["MA2C", d]["return: IQM [95 % CI]"],
    "the paper's MA2C": lambda rows, d: rows["MA2C", d]["return (paper)"],
    "MA2C, the authors' reward (no penalty)": lambda rows, d: rows["no penalty (the authors' reward)", d][
        "return: mean ± std over seeds"
    ],
    "MA2C collision rate / lane changes per episode": lambda rows, d: (
        f"{rows['MA2C', d]['collision rate']} / {rows['MA2C', d]['lane changes / ep.']}"
    ),
    "MA2C acceleration std [m/s²]": lambda rows, d: rows["MA2C", d]["accel. std [m/s²]"],
}


def test_the_results_readmes_ma2c_detail_is_the_committed_table(committed_rows):
    rows = _readme_table(RESULTS / "README.md", ["", *DENSITIES])
    assert [row[""] for row in rows] == list(MA2C_DETAIL_ROWS)
    for row in rows:
        for density, column in enumerate(DENSITIES, start=1):
            assert row[column] == MA2C_DETAIL_ROWS[row[""]](committed_rows, density), (row[""], density)


def test_status_piped_into_head_stops_quietly():
    import subprocess
    import sys

    executable = Path(sys.executable).parent / "sb3-marl"
    piped = subprocess.run(
        f"'{executable}' benchmark status --seeds 3 -f '{PAPER_GRID}' | head -n 1",
        shell=True,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert piped.stdout.startswith("Benchmark grid 'paper' in ") and piped.stderr == ""


def test_the_rule_prior_readme_quotes_its_heldout_table():
    """results/rule-prior/README.md's table of the policy alone is heldout.md's, number for number."""
    folder = RESULTS / "rule-prior"
    heldout = {
        (row["actions"], row["density"], row["supervisor"]): row
        for table in markdown_tables((folder / "heldout.md").read_text())
        for row in table
        if row["policy"] == "ma2c rule-prior" or row["policy"] == "IDM/MOBIL"
    }
    (alone,) = [t for t in markdown_tables((folder / "README.md").read_text()) if "policy alone (no supervisor)" in t[0]]
    for row in alone:
        actions = "sampled" if "sampled" in row["policy alone (no supervisor)"] else "greedy"
        measured = heldout[(actions, row["density"], "off")]
        assert row["collisions"].split(" (")[0] == measured["collisions"]
        assert row["return"] == measured["return"]
        assert row["IDM/MOBIL's return"] == heldout[("rules", row["density"], "off")]["return"].split(" ±")[0]
