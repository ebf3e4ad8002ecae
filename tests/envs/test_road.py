"""Road geometry, random spawn and HDV behaviour parameters."""

import numpy as np
import pytest
from helpers import make
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.controller import MDPVehicle


def test_road_is_one_way_two_lanes_of_520_m():
    env = make(1)
    env.reset(seed=0)
    lanes = env.road.network.lanes_list()
    assert len(lanes) == 2
    for k, lane in enumerate(lanes):
        assert lane.length == pytest.approx(520.0)
        assert lane.width_at(0) == pytest.approx(4.0)
        np.testing.assert_allclose(lane.start, [0.0, 4.0 * k])
        np.testing.assert_allclose(lane.direction, [1.0, 0.0])  # one way: +x


@pytest.mark.parametrize("density, hdv_range", [(1, (1, 3)), (2, (2, 4)), (3, (4, 6))])
def test_spawn_counts_speeds_and_spacing(density, hdv_range):
    env = make(density)
    seen_hdv_counts = set()
    for seed in range(30):
        env.reset(seed=seed)
        avs = [v for v in env.road.vehicles if isinstance(v, MDPVehicle)]
        hdvs = [v for v in env.road.vehicles if not isinstance(v, MDPVehicle)]
        assert len(avs) == env.n_avs
        assert hdv_range[0] <= len(hdvs) <= hdv_range[1]
        seen_hdv_counts.add(len(hdvs))
        assert all(isinstance(v, IDMVehicle) for v in hdvs)
        for vehicle in env.road.vehicles:
            assert 25.0 <= vehicle.speed <= 30.0
            assert vehicle.heading == 0.0
            slot = (vehicle.position[0] - 10.0) / 40.0
            assert abs(slot - round(slot)) * 40.0 <= 1.5 + 1e-9  # grid slot 40 m apart, +-1.5 m noise
        for lane in (0, 1):
            xs = np.sort([v.position[0] for v in env.road.vehicles if v.lane_index[2] == lane])
            assert np.all(np.diff(xs) >= 40.0 - 3.0 - 1e-9)  # never overlapping (length 5 m)
    assert seen_hdv_counts == set(range(hdv_range[0], hdv_range[1] + 1))


@pytest.mark.parametrize("politeness", [0.0, 1.0])
def test_mobil_parameters_on_every_hdv(politeness):
    env = make(3, hdv_politeness=politeness)
    for seed in range(5):
        env.reset(seed=seed)
        for _ in range(3):
            hdvs = env.road.vehicles[env.n_avs :]
            assert hdvs
            for hdv in hdvs:
                assert politeness == hdv.POLITENESS
                assert hdv.LANE_CHANGE_MAX_BRAKING_IMPOSED == 9.0
                assert hdv.LANE_CHANGE_MIN_ACC_GAIN == 0.1
            *_, terminated, truncated, _ = env.step(np.ones(env.n_avs, dtype=int))
            if terminated or truncated:
                break


def test_politeness_changes_mobil_decisions():
    """An HDV stuck behind a slow leader changes lane when selfish (p=0), not when polite (p=1).

    The move would make the fast AV behind in the target lane brake (within b_safe = 9 m/s²), a
    loss the polite driver weighs against its own gain.
    """
    decisions = {}
    for politeness in (0.0, 1.0):
        env = make(1, n_avs=1, hdv_politeness=politeness)
        env.reset(seed=0)
        env.place(avs=[(45.0, 1, 30.0)], hdvs=[(100.0, 0, 25.0), (160.0, 0, 22.0)])
        hdv = env.road.vehicles[1]
        decisions[politeness] = hdv.mobil(("start", "end", 1))
    assert decisions == {0.0: True, 1.0: False}
