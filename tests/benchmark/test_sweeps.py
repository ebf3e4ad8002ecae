"""`sb3-marl sweep generalisation` and `sweep penetration` on the committed grid: every trained
agent of a name on every scenario id and politeness; every AV share of a fixed number of vehicles,
the all-human reference at 0 %."""

import json

import imageio.v2 as imageio
import numpy as np

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
    assert imageio.imread(tmp_path / "generalisation.png").std() > 0


def test_bad_politeness_and_unknown_agents_are_usage_errors(tmp_path, capsys):
    assert main(["sweep", "generalisation", "--politeness", "2", "-o", str(tmp_path)]) == 2
    assert "--politeness" in capsys.readouterr().err
    assert main(["sweep", "generalisation", "--trained", "fastest", "--seeds", "1", "-o", str(tmp_path)]) == 2
    assert "no trained agent ['fastest']" in capsys.readouterr().err


def test_the_penetration_sweep_holds_the_vehicles_and_varies_the_avs(tmp_path, capsys):
    argv = ["sweep", "penetration", "--env", "sb3_marl/Merge-density1-v0", "--vehicles", "4", "--shares", "0", "50", "100"]
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
    assert imageio.imread(tmp_path / "penetration.png").std() > 0
    assert main(["sweep", "penetration", "--shares", "120", "-o", str(tmp_path)]) == 2
