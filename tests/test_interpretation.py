"""The paper's policy interpretation (experiment 6): finding and drawing a cooperative lane change."""

from pathlib import Path

import numpy as np
import pytest

from sb3_marl.algos.common.policies import model_policy
from sb3_marl.envs.lane_change_env import ACTION_INDEX
from sb3_marl.evaluation import EpisodeTrace
from sb3_marl.evaluation.interpretation import find_cooperative_lane_change, plot_cooperative_lane_change
from sb3_marl.evaluation.metrics import YIELD_GAP_M
from sb3_marl.runs.folders import find_run

#: A committed full-budget MA2C model at density 3 trained without the intervention penalty (it
#: weaves: dozens of yields in 30 episodes; results/README.md)
TRIAL = Path(__file__).resolve().parents[1] / "results/paper-grid/trials/ma2c_density3_no-intervention-penalty_seed0"
ENV_ID = "sb3_marl/LaneChange-density3-v0"


def _trace(follower_actions: list[str], follower_offset: float = -20.0, steps: int = 14, change_at: int = 6) -> EpisodeTrace:
    """AV 0 drives in lane 0 and starts a lane change into lane 1 at ``change_at``; AV 1 drives in
    lane 1, ``follower_offset`` m from AV 0, braking from 25 m/s once it executes SLOWER."""
    trace = EpisodeTrace(seed=7, n_avs=2)
    speed = 25.0
    for step in range(steps):
        action = follower_actions[step] if step < len(follower_actions) else "IDLE"
        if ACTION_INDEX[action] == ACTION_INDEX["SLOWER"] or speed < 25.0:
            speed = max(20.0, speed - 1.0)
        trace.x.append(np.array([100.0 + 5.0 * step, 100.0 + follower_offset + 5.0 * step]))
        trace.lane.append(np.array([0, 1]))
        trace.target_lane.append(np.array([1 if step >= change_at else 0, 1]))
        trace.speed.append(np.array([25.0, speed]))
        trace.executed.append(np.array([ACTION_INDEX["IDLE"], ACTION_INDEX[action]]))
        trace.lane_change.append(np.array([step == change_at, False]))
    return trace


def test_a_follower_that_slows_for_a_lane_change_into_its_lane_yields():
    slows = ["IDLE"] * 4 + ["SLOWER"] + ["IDLE"] * 9
    (event,) = _trace(slows).yields()
    assert (event.episode_seed, event.step, event.changer, event.yielder) == (7, 6, 0, 1)
    assert event.speed_drop == pytest.approx(25.0 - 20.0)  # 25 m/s before the window, 20 m/s after the change
    assert _trace(["IDLE"] * 14).yields() == []  # did not slow down
    assert _trace(["SLOWER"] + ["IDLE"] * 13).yields() == []  # slowed, but long before the lane change
    assert _trace(slows, follower_offset=+20.0).yields() == []  # ahead of the lane-changing AV, not behind
    assert _trace(slows, follower_offset=-(YIELD_GAP_M + 1)).yields() == []  # too far behind to matter


def test_a_trained_ma2c_yields_and_the_figure_replays_the_episode(tmp_path):
    run = find_run(TRIAL, "ma2c", ENV_ID)
    policy = model_policy(run.load_model("cpu"))
    event, count = find_cooperative_lane_change(policy, ENV_ID, 10, 10_000, run.env_config)
    assert count >= 1 and event.speed_drop > 0 and event.changer != event.yielder
    assert 10_000 <= event.episode_seed < 10_010
    assert find_cooperative_lane_change(policy, ENV_ID, 10, 10_000, run.env_config) == (event, count)  # seeded
    path = plot_cooperative_lane_change(policy, ENV_ID, event, tmp_path / "coop.png", run.env_config)
    assert path.read_bytes()[:4] == b"\x89PNG" and path.stat().st_size > 50_000
