"""`sb3-marl sweep generalisation` and `sweep penetration` on the committed grid: every trained
agent of a name on every scenario id and politeness; every AV share of a fixed number of vehicles,
the all-human reference at 0 %."""

import json

import numpy as np
from figures import figure_size, legend_labels, panels, png_size, saved_figures

from sb3_marl.cli import main


def test_the_matrix_has_every_agent_and_condition(tmp_path, capsys):
    argv = [
        "sweep",
        "generalisation",
        "--trained",
        "safe",
        "--seeds",
        "1",
        "--eval-episodes",
        "1",
        "--politeness",
        "0",
        "1",
        "--styles",
        "timid",
    ]
    with saved_figures() as figures:
        assert main([*argv, "-o", str(tmp_path)]) == 0
    result = json.loads((tmp_path / "generalisation.json").read_text())
    # `safe` exists on the lane change's three densities only; six scenario ids x (two politeness values, timid HDVs)
    assert [row["trained_env"] for row in result["rows"]] == [f"sb3_marl/LaneChange-density{d}-v0" for d in (1, 2, 3)]
    assert len(result["conditions"]) == 18 and {"Merge-density3, p=1", "LaneChange-density2, timid"} <= set(
        result["conditions"]
    )
    for row in result["rows"]:
        assert set(row["cells"]) == set(result["conditions"])
        assert all(cell["episodes"] == 1 and 0 <= cell["collision_rate_alone"] <= 1 for cell in row["cells"].values())
    out = capsys.readouterr().out
    assert "| safe: LaneChange-density3 |" in out and "Collision rate alone" in out

    # the cells are evaluated under their condition: the same held-out episodes give other returns
    # where the HDVs are polite (p=1) or timid than in the training condition (p=0, normal), on
    # some road for every agent (the roads where no HDV meets a choice politeness or style changes
    # give the same episode)
    for changed in ("p=1", "timid"):
        for row in result["rows"]:
            cells = row["cells"]
            roads = {label.split(",")[0] for label in cells}
            differ = [road for road in roads if cells[f"{road}, {changed}"] != cells[f"{road}, p=0"]]
            assert differ, (changed, row["trained_env"])

    # the figure: one heatmap per measure, one row per agent, one column per condition, the cells'
    # values; a box on each agent's training condition
    path = tmp_path / "generalisation.png"
    figure = figures[path]
    assert png_size(path) == figure_size(figure)
    labels = [f"safe: {row['trained_env'].split('/')[-1].removesuffix('-v0')}" for row in result["rows"]]
    for ax, key in zip(panels(figure), ("return_mean", "collision_rate_alone"), strict=True):
        (image,) = ax.get_images()
        expected = [[row["cells"][c][key] for c in result["conditions"]] for row in result["rows"]]
        np.testing.assert_array_equal(image.get_array(), expected, err_msg=key)
        assert [tick.get_text() for tick in ax.get_xticklabels()] == result["conditions"]
        assert [tick.get_text() for tick in ax.get_yticklabels()] == labels
        boxes = [(patch.get_x() + 0.5, patch.get_y() + 0.5) for patch in ax.patches]
        trained = [f"{label.split(': ')[1]}, p=0" for label in labels]
        assert boxes == [(result["conditions"].index(c), i) for i, c in enumerate(trained)], key


def test_bad_politeness_and_unknown_agents_are_usage_errors(tmp_path, capsys):
    assert main(["sweep", "generalisation", "--politeness", "2", "-o", str(tmp_path)]) == 2
    assert "--politeness" in capsys.readouterr().err
    assert main(["sweep", "generalisation", "--trained", "fastest", "--seeds", "1", "-o", str(tmp_path)]) == 2
    assert "no trained agent ['fastest']" in capsys.readouterr().err


def test_the_penetration_sweep_holds_the_vehicles_and_varies_the_avs(tmp_path, capsys):
    argv = ["sweep", "penetration", "--env", "sb3_marl/Merge-density1-v0", "--vehicles", "4", "--shares", "0", "50", "100"]
    with saved_figures() as figures:
        assert main([*argv, "--eval-episodes", "1", "-o", str(tmp_path)]) == 0
    result = json.loads((tmp_path / "penetration.json").read_text())
    rows = [(r["share"], r["n_avs"], r["policy"], r["supervisor"]) for r in result["rows"]]
    assert rows[0] == (0, 0, "all human (no AV)", "-")
    assert sorted(rows[1:]) == sorted(
        (share, n, policy, supervisor)
        for share, n in ((50, 2), (100, 4))
        for policy in ("ma2c (paper)", "idm-mobil")
        for supervisor in ("on", "off")
    )
    assert all(np.isnan(r["traffic"]["time_loss_s_per_km_hdv"]) for r in result["rows"] if r["n_avs"] == 4)  # no HDV left
    assert "| 2 of 4 | ma2c (paper) | on |" in capsys.readouterr().out

    # the figure: one panel per measure against the AV share, a line per policy and protocol
    # through its rows' values, the all-human reference a point at 0 %
    from sb3_marl.benchmark.penetration import PLOTTED

    path = tmp_path / "penetration.png"
    figure = figures[path]
    assert png_size(path) == figure_size(figure) == (1300, 650)
    lines = sorted({(r["policy"], r["supervisor"]) for r in result["rows"] if r["n_avs"] > 0})
    labels = [f"{policy}, supervisor {supervisor}" for policy, supervisor in lines]
    assert legend_labels(figure) == [*labels, "all human (no AV)"]
    for ax, (key, title) in zip(panels(figure), PLOTTED.items(), strict=True):
        assert ax.get_title() == title and ax.get_xlabel() == "AV share [%]"
        drawn = {line.get_label(): line.get_xydata().tolist() for line in ax.get_lines()}
        for label, (policy, supervisor) in zip(labels, lines, strict=True):
            mine = [r for r in result["rows"] if (r["policy"], r["supervisor"]) == (policy, supervisor)]
            expected = [[100 * r["n_avs"] / 4, r.get(key, r["traffic"].get(key, np.nan))] for r in mine]
            np.testing.assert_array_equal(drawn[label], expected, err_msg=f"{key}: {label}")
        human = result["rows"][0]
        np.testing.assert_array_equal(drawn["all human (no AV)"], [[0, human.get(key, human["traffic"].get(key, np.nan))]])
    assert main(["sweep", "penetration", "--shares", "120", "-o", str(tmp_path)]) == 2
