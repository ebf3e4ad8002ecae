"""The traffic view (sb3_marl.evaluation.trips): trip records and metrics on scenes whose answers
are known by hand, and on real episodes of both roads."""

import io
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from documents import commands

from sb3_marl.envs import av_counts, make_scenario
from sb3_marl.evaluation import evaluate_protocols
from sb3_marl.evaluation.baselines import IDMMobilPolicy
from sb3_marl.evaluation.trips import TRIP_COLUMNS, TripRecorder, human_reference, trips_csv
from sb3_marl.sim import kernel

DT = 0.2  # [s] the policy step at 5 Hz


def _scene():
    """An AV at 100 m and 25 m/s closing on an HDV at 130 m and 15 m/s in the same lane."""
    env = make_scenario("sb3_marl/LaneChange-density1-v0", {"n_avs": 1})
    env.reset(seed=0)
    env.place(avs=[(100.0, 0, 25.0)], hdvs=[(130.0, 0, 15.0)])
    recorder = TripRecorder()
    recorder(env, {"step": 0})
    return env, recorder


def _set(env, row, x, speed):
    env.state[row, kernel.X], env.state[row, kernel.SPEED] = x, speed


def test_ttc_headway_braking_and_times_of_a_hand_built_scene():
    env, recorder = _scene()
    # step 1: the HDV brakes from 15 to 12 m/s (15 m/s² over 0.2 s); gap 28 - 5 = 23 m, closing 13 m/s
    _set(env, 0, 105.0, 25.0)
    _set(env, 1, 133.0, 12.0)
    recorder(env, {"step": 1})
    # step 2: the HDV has left the road (its row removed, as the kernel does past 520 m); the AV stops
    env.state = env.state[:1].copy()
    _set(env, 0, 110.0, 0.05)
    recorder(env, {"step": 2})
    av, hdv = recorder.trips()
    assert av["minTTC"] == pytest.approx(min(25 / 10, 23 / 13)) and av["minTimeHeadway"] == pytest.approx(23 / 25)
    assert av["maxDecel"] == pytest.approx((25 - 0.05) / DT) and av["waitingTime"] == pytest.approx(DT)
    assert av["timeLoss"] == pytest.approx(DT * (1 - 25 / 30) + DT * (1 - 0.05 / 30))  # ideal: the ladder's 30 m/s
    assert np.isnan(av["arrival"]) and av["duration"] == pytest.approx(2 * DT) and av["routeLength"] == pytest.approx(10.0)
    assert (hdv["vType"], hdv["arrival"], hdv["arrivalPos"], hdv["routeLength"]) == (
        "HDV",
        pytest.approx(2 * DT),
        520.0,
        390.0,
    )
    assert hdv["maxDecel"] == pytest.approx(15.0) and np.isnan(hdv["minTTC"]) and not hdv["crashed"]
    metrics = recorder.metrics()
    assert metrics["ttc_below_3.0_share"] == pytest.approx(2 / 5)  # the AV at steps 0 and 1, of 5 vehicle-steps
    assert metrics["ttc_below_1.5_share"] == 0.0
    assert metrics["hdv_hard_brakes_per_km"] == pytest.approx(1 / 0.003)  # one onset over the HDV's 3 m
    assert metrics["throughput_veh_h"] == pytest.approx(1 / (2 * DT / 3600))
    assert metrics["time_headway_median"] == pytest.approx(np.median([25 / 25, 23 / 25]))


def test_a_vehicle_with_no_leader_and_one_beside_has_no_ttc():
    """A vehicle ahead in the other lane is no leader: no TTC, no headway."""
    env = make_scenario("sb3_marl/LaneChange-density1-v0", {"n_avs": 1})
    env.reset(seed=0)
    env.place(avs=[(100.0, 0, 25.0)], hdvs=[(110.0, 1, 15.0)])
    recorder = TripRecorder()
    recorder(env, {"step": 0})
    av, _ = recorder.trips()
    assert np.isnan(av["minTTC"]) and np.isnan(av["minTimeHeadway"])


@pytest.mark.parametrize("env_id", ["sb3_marl/LaneChange-density3-v0", "sb3_marl/Merge-density3-v0"])
def test_trip_records_of_real_episodes_are_consistent(env_id):
    """Every vehicle of every episode has one record; AVs are the first ids; times and distances
    are within the road and the episode; the CSV reads back with pandas; recording changes nothing
    of the RL evaluation."""
    plain = evaluate_protocols(IDMMobilPolicy(), env_id, 4, seed=7)
    result = evaluate_protocols(IDMMobilPolicy(), env_id, 4, seed=7, traffic=True)
    assert result["returns"] == plain["returns"] and result["supervisor_off"]["returns"] == plain["supervisor_off"]["returns"]
    trips = pd.read_csv(io.StringIO(trips_csv(result["trips"])))
    assert list(trips.columns) == list(TRIP_COLUMNS) and trips["seed"].nunique() == 4
    for _, episode in trips.groupby("seed"):
        assert list(episode["id"]) == list(range(len(episode)))
        avs = episode["vType"] == "AV"
        assert avs.any() and avs.iloc[: avs.sum()].all()  # AVs first
    assert (trips["duration"] <= 20.0 + 1e-9).all() and (trips["routeLength"] >= 0).all()
    assert (trips["arrivalPos"] <= 520.0 + 1e-9).all() and (
        trips["arrival"].dropna() == trips["duration"][trips["arrival"].notna()]
    ).all()
    metrics = result["traffic"]
    assert metrics["flow_veh_h"] > 0 and metrics["density_veh_km"] > 0 and 0 <= metrics["ttc_below_1.5_share"] <= 1


@pytest.mark.parametrize("env_id", ["sb3_marl/LaneChange-density2-v0", "sb3_marl/Merge-density2-v0"])
def test_the_all_human_reference_has_no_av_and_the_same_vehicles(env_id):
    """The reference plays the policies' episodes (same seeds, same AV counts cycling) with every AV
    an HDV: per episode the same vehicle count and spawn positions, and no AV."""
    policy = evaluate_protocols(IDMMobilPolicy(), env_id, 3, seed=11, traffic=True)["trips"]
    human = human_reference(env_id, 3, seed=11).trips()
    assert {trip["vType"] for trip in human} == {"HDV"}
    for key in ("seed", "id", "departPos"):
        assert [trip[key] for trip in human] == [trip[key] for trip in policy], key


def test_the_docs_command_runs_verbatim(tmp_path):
    """docs/traffic.md's command, as written, from an empty folder: the traffic table with the
    all-human row, and the trip records where the page says."""
    (line,) = commands("traffic.md", "Traffic impact")
    completed = subprocess.run(
        [str(Path(sys.executable).parent / "sb3-marl"), *shlex.split(line)[1:]],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert completed.returncode == 0, completed.stderr[-2000:]
    assert "| all human (no AV) | - | - |" in completed.stdout and "| ma2c (safe) |" in completed.stdout
    trips = pd.read_csv(tmp_path / "logs/trained-agents/ma2c_density3_rule-prior-agreement-0.5_seed0/evaluation_trips.csv")
    assert set(trips["policy"]) == {"ma2c (safe)", "idm-mobil", "all human (no AV)"}


def test_time_space_diagram_and_encounters_figures(tmp_path):
    """A row of lane panels per policy, every vehicle's trajectory drawn in the panel of its lane
    band (the AVs' also as thick lines, in the policy's row only); the encounter histograms of each
    policy's trips, each the share of its vehicles with a finite minimum."""
    from figures import legend_labels, panels, png_size, saved_figures

    from sb3_marl.evaluation.episodes import run_episodes
    from sb3_marl.evaluation.traffic_plots import BAND, SPEED_RANGE, PositionTrace, plot_encounters, plot_time_space

    env_id = "sb3_marl/LaneChange-density2-v0"
    policy, human, policy_trips = PositionTrace(), PositionTrace(), TripRecorder()

    def record(env, info):
        policy(env, info)
        policy_trips(env, info)

    run_episodes(make_scenario(env_id, {"n_avs": av_counts(env_id)[0]}), IDMMobilPolicy(), 1, seed=3, on_step=record)
    reference = human_reference(env_id, 1, seed=3, also=(human,))
    assert set(policy.rows[:, 1].astype(int)) == set(human.rows[:, 1].astype(int))  # the same vehicles
    assert policy.rows[:, 5].any() and not human.rows[:, 5].any()  # AVs only in the policy's episode
    traces = {"idm-mobil": policy, "all human": human}
    trips = {"idm-mobil": policy_trips.trips(), "all human": reference.trips()}
    with saved_figures() as figures:
        time_space = figures[plot_time_space(traces, tmp_path / "ts.png")]
        encounters = figures[plot_encounters(trips, tmp_path / "enc.png")]

    assert png_size(tmp_path / "ts.png") == (2 * 420, 2 * 320)  # two rows of two lane panels, 100 dpi
    axes = iter(panels(time_space))
    for label, trace in traces.items():
        rows = trace.rows
        band = np.floor((rows[:, 3] + BAND / 2) / BAND).clip(0, None)
        thick: set[tuple[float, float]] = set()
        for b in (0, 1):
            ax = next(axes)
            assert ax.get_title() == f"{label}: lane band {b}"
            mine = rows[band == b]
            drawn = {tuple(point) for lines in ax.collections for segment in lines.get_segments() for point in segment}
            expected = {(t, x) for t, x in mine[:, [0, 2]]}
            assert drawn <= expected and len(drawn) >= 0.95 * len(expected), (label, b)  # all but lone samples
            colours = np.concatenate([lines.get_array() for lines in ax.collections])
            assert set(colours) <= set(mine[:, 4])  # coloured by speed, on one scale
            assert {lines.get_clim() for lines in ax.collections} == {SPEED_RANGE}
            avs = {(t, x) for line in ax.get_lines() for t, x in line.get_xydata()}
            assert avs <= {(t, x) for t, x in mine[mine[:, 5] == 1][:, [0, 2]]}  # thick lines: the AVs'
            thick |= avs
        assert len(thick) >= 0.95 * rows[:, 5].sum()  # every AV, in the policy's row only
    assert next(axes, None) is None

    ttc, headway = panels(encounters)
    assert legend_labels(ttc) == list(trips)
    assert ttc.get_xlabel().startswith("minimum TTC [s]") and headway.get_xlabel().startswith("minimum time headway")
    for ax, column in ((ttc, "minTTC"), (headway, "minTimeHeadway")):
        assert [steps.get_label() for steps in ax.patches] == list(trips)
        for steps, records in zip(ax.patches, trips.values(), strict=True):
            values = np.array([trip[column] for trip in records], dtype=float)
            assert steps.get_data().values.sum() == pytest.approx(np.isfinite(values).mean()), column


def test_timid_hdvs_keep_longer_time_gaps_than_aggressive_ones():
    """The all-human road of the same episodes under each HDV style (IDM's T: 2.0, 1.5, 1.0 s)."""
    headway = {
        style: human_reference("sb3_marl/LaneChange-density3-v0", 6, seed=5, config={"hdv_style": style}).metrics()[
            "time_headway_median"
        ]
        for style in ("timid", "normal", "aggressive")
    }
    assert headway["timid"] > headway["normal"] > headway["aggressive"], headway
