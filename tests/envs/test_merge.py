"""The on-ramp merging scenario (sb3_marl/Merge-density{1,2,3}-v0): MARL_CAVs' road, spawn, reward and
neighbour sets on the lane change's kernel, held to highway-env's own classes on the same road."""

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from parity import compare, run_episode, stock_rule_actions
from pettingzoo.test import parallel_api_test

from sb3_marl.envs import ENV_IDS, MERGE_ENV_IDS, av_counts, parallel_env
from sb3_marl.safety.supervisor import supervisor_switches
from sb3_marl.sim import kernel
from sb3_marl.sim.lanes import lane_table
from sb3_marl.sim.merge_road import (
    CONVERGING,
    MAIN_BEFORE,
    MAIN_BESIDE,
    MAIN_SPAWN,
    MERGE_END,
    MERGING_LANE,
    RAMP,
    RAMP_SPAWN,
    RAMP_Y,
    make_merge_road,
    merge_lanes,
)
from sb3_marl.sim.simulator import COMPILED, STOCK, capture, lane_indices
from wrappers import ParameterSharingVecEnv

TOLERANCE = 1e-9  # [m, rad, m/s, m/s²], as tests/envs/test_kernel.py


def make(density: int = 1, **config):
    return gym.make(MERGE_ENV_IDS[density], config=config).unwrapped


@pytest.mark.parametrize("density", [1, 2, 3])
@pytest.mark.parametrize(("policy", "config"), [("uniform", {}), ("cruise", {}), ("cruise", {"safety_supervisor": True})])
def test_compiled_kernel_matches_highway_env_on_the_merge_road(density, policy, config):
    result = compare(STOCK, COMPILED, MERGE_ENV_IDS[density], range(8), policy, **config)
    assert result.different_outcomes == []
    assert result.max_state_difference < TOLERANCE
    assert result.max_observation_difference < TOLERANCE
    if not config:
        assert result.crashes >= 4  # collisions, the obstacle's included, and their impacts
    assert result.hdv_lane_changes >= 2  # the ramp's HDVs merge by MOBIL


def test_lane_table_reads_the_road_highway_env_builds():
    road = make_merge_road({"speed_limit": 30.0, "show_trajectories": False}, np.random.default_rng(0))
    table = merge_lanes(30.0)
    np.testing.assert_array_equal(table, lane_table(road.network))
    indices = lane_indices(road.network)
    assert [indices[k] for k in (MAIN_BEFORE, MAIN_BESIDE, MERGING_LANE, RAMP, CONVERGING)] == [
        ("a", "b", 0),
        ("b", "c", 0),
        ("b", "c", 1),
        ("j", "k", 0),
        ("k", "b", 0),
    ]
    assert road.objects[0].position.tolist() == [MERGE_END, 4.0]


@pytest.mark.parametrize("density", [1, 2, 3])
def test_spawn_is_marl_cavs(density):
    """Half the AVs (rounded down) on the main road, the others on the ramp, then the HDVs the same
    way, on the spawn points +- 1.5 m, at 25-27 m/s; the obstacle last."""
    lo, hi = {1: (1, 3), 2: (2, 4), 3: (3, 5)}[density]
    for n_avs in av_counts(MERGE_ENV_IDS[density]):
        env = make(density, n_avs=n_avs)
        for seed in range(5):
            env.reset(seed=seed)
            state, n_hdvs = env.state, env.n_hdvs
            assert lo <= n_hdvs <= hi and state.shape[0] == n_avs + n_hdvs + 1
            assert state[-1, kernel.IS_OBSTACLE] == 1 and not state[:-1, kernel.IS_OBSTACLE].any()
            for rows, main in ((slice(0, n_avs), n_avs // 2), (slice(n_avs, n_avs + n_hdvs), n_hdvs // 2)):
                vehicles = state[rows]
                on_ramp = vehicles[:, kernel.LANE] == RAMP
                assert (~on_ramp).sum() == main and (vehicles[on_ramp, kernel.Y] == RAMP_Y).all()
                assert (vehicles[~on_ramp, kernel.LANE] == MAIN_BEFORE).all() and (vehicles[~on_ramp, kernel.Y] == 0).all()
                for x, points in ((vehicles[~on_ramp, kernel.X], MAIN_SPAWN), (vehicles[on_ramp, kernel.X], RAMP_SPAWN)):
                    assert all(min(abs(p - v) for p in points) <= 1.5 for v in x)
            speeds = state[:-1, kernel.SPEED]
            assert ((speeds >= 25) & (speeds <= 27)).all()


def test_merging_lane_cost_and_reward():
    """An AV on the merging lane pays 4 × exp(-(x - 420)² / 1000) more than one on the main road."""
    env = make(1, n_avs=2, safety_supervisor=False)
    env.reset(seed=0)
    _, info = env.place([(400.0, MERGING_LANE, 25.0), (250.0, MAIN_BEFORE, 25.0)])
    cost = info["reward_terms"]["merging_lane"]
    np.testing.assert_allclose(cost, [-np.exp(-((400.0 - MERGE_END) ** 2) / 1000.0), 0.0])
    speed = info["reward_terms"]["speed"]
    np.testing.assert_allclose(info["rewards"], speed + 4 * cost)  # no leader within 60 m, no comfort term


def test_regional_neighbours_see_across_the_ramp():
    """MARL_CAVs' regional sets: the AVs just ahead and behind, by x, among the vehicles of the own
    lane's route (the ramp's straight section and the converging section are one route), and on the
    main road past the ramp's start the converging section's, and the reverse."""
    env = make(3, n_avs=4)
    env.reset(seed=0)
    _, info = env.place(
        [(260.0, MAIN_BEFORE, 25.0), (250.0, CONVERGING, 25.0), (100.0, MAIN_BEFORE, 25.0), (90.0, RAMP, 25.0)]
    )
    assert [set(np.flatnonzero(row)) for row in info["neighbours"]] == [{0, 1, 2}, {0, 1, 2, 3}, {0, 2}, {1, 3}]


def test_rule_driver_matches_highway_env_on_the_merge_road():
    checked = 0
    for density in (1, 3):
        env = make(density)
        rng = np.random.default_rng(density)
        for seed in range(6):
            _, info = env.reset(seed=seed)
            for _ in range(60):
                np.testing.assert_array_equal(env.rule_actions(), stock_rule_actions(env))
                checked += 1
                _, _, terminated, truncated, info = env.step(
                    np.array([rng.choice(np.flatnonzero(m)) for m in info["action_mask"]])
                )
                if terminated or truncated:
                    break
    assert checked > 200


def test_state_round_trips_through_highway_env_objects():
    env = make(3)
    env.reset(seed=1)
    road = env.road
    np.testing.assert_array_equal(capture(road.vehicles, road.network, road.objects), env.state)


@pytest.mark.parametrize(
    ("make_env", "key"),
    [
        (lambda: gym.make(MERGE_ENV_IDS[1], config={"lanes_count": 3}), "lanes_count"),
        (lambda: gym.make(ENV_IDS[1], config={"merging_lane_weight": 1.0}), "merging_lane_weight"),
        (lambda: gym.make(MERGE_ENV_IDS[1], config={"merging_lane_weight": -1.0}), "merging_lane_weight"),
        (lambda: gym.make(MERGE_ENV_IDS[3], config={"hdv_count_range": [0, 9]}), "hdv_count_range"),
        (lambda: gym.make(MERGE_ENV_IDS[1], config={"n_avs": 5}), "n_avs"),
        (lambda: gym.make(MERGE_ENV_IDS[1], config={"supervisor_version": 3}), "supervisor_version"),
    ],
)
def test_bad_config_names_the_key(make_env, key):
    with pytest.raises(ValueError, match=key):
        make_env()


def test_parameter_sharing_and_pettingzoo_run_the_merge_ids():
    venv = ParameterSharingVecEnv(MERGE_ENV_IDS[2], seed=0)
    assert venv.num_envs == 2 + 3 + 4
    venv.reset()
    for _ in range(5):
        venv.step(np.ones(venv.num_envs, dtype=np.int64))
    venv.close()
    merge = parallel_env(density=1, scenario="merge", safety_supervisor=True)
    parallel_api_test(merge, num_cycles=100)
    assert merge.metadata["name"] == "sb3_marl_merge_v0"
    assert parallel_env(density=1).metadata["name"] == "sb3_marl_lane_change_v0"


def test_a_seed_gives_the_same_episode():
    a = run_episode(COMPILED, MERGE_ENV_IDS[2], seed=3, policy="cruise")
    b = run_episode(COMPILED, MERGE_ENV_IDS[2], seed=3, policy="cruise")
    assert a.events == b.events and all((s == t).all() for s, t in zip(a.states, b.states))


def test_supervisor_merges_before_the_merging_lane_ends():
    """An AV cruising toward the obstacle is made to leave the merging lane while it still can; with
    the main road beside it taken, it slows down instead of cutting in."""
    env = make(1, n_avs=1, safety_supervisor=True)
    env.reset(seed=0)
    env.place([(360.0, MERGING_LANE, 20.0)])
    executed, rooms, _ = env.supervisor(env.state, 1, np.array([1]), env.action_masks())
    assert executed.tolist() == [0] and rooms[0] > 2.0  # LANE_LEFT
    env.place([(360.0, MERGING_LANE, 20.0)], hdvs=[(361.0, MAIN_BESIDE, 20.0)])
    executed, _, _ = env.supervisor(env.state, 1, np.array([1]), env.action_masks())
    assert executed.tolist() == [4]  # SLOWER: the lane beside is taken


@pytest.mark.parametrize("simulator", [COMPILED, STOCK])
def test_the_emergency_brake_stops_an_av_for_a_stalled_vehicle(simulator):
    """An AV at the ladder's lowest speed (10 m/s) closing on a stalled HDV has no meta-action with
    room: without the emergency brake it runs into it; with it (the merge's default) the supervisor
    brakes it (target speed 0 m/s), on the compiled road and on highway-env's objects alike."""
    outcome = {}
    for brake in (False, True):
        env = make(1, n_avs=1, safety_supervisor=True, supervisor_emergency_brake=brake)
        env.simulator = simulator
        env.reset(seed=0)
        env.place([(100.0, MAIN_BEFORE, 10.0)], hdvs=[(112.0, MAIN_BEFORE, 0.0)])
        braked, crashed = [], False
        for _ in range(10):
            _, _, terminated, _, info = env.step(np.array([1]))
            braked.append(bool(info["emergency_brake"][0]))
            crashed = crashed or bool(info["crashed"][0])
            if terminated:
                break
        outcome[brake] = (crashed, braked[0], float(env.state[0, kernel.TARGET_SPEED]))
    assert outcome[False][:2] == (True, False)
    assert outcome[True][:2] == (False, True) and info["intervened"][0] == braked[-1]
    assert supervisor_switches(make(1).config) == (True, True, False)


def random_episode_crashes(seed: int, n_avs: int, **config) -> bool:
    """Whether episode ``seed`` of benchmarks/supervisor_safety.py's random policy (each AV's
    meta-action drawn among its available ones) at density 3, behind the supervisor, crashes."""
    from sb3_marl.evaluation import run_episodes

    rng = np.random.default_rng(seed)

    def policy(env, obs):
        return np.array([rng.choice(np.flatnonzero(mask)) for mask in env.action_masks()])

    return run_episodes(make(3, n_avs=n_avs, safety_supervisor=True, **config), policy, 1, seed)[0].crashed


def test_the_joint_search_avoids_a_crash_that_serving_one_av_at_a_time_leaves():
    """Density 3, 6 AVs, each AV's meta-action drawn among its available ones (episode 200614 of
    benchmarks/supervisor_safety.py): served one at a time, the AVs end in a crash at step 78; with
    ``supervisor_joint_search`` (the merge's default) the short AV's options are searched with each
    other AV's and the episode runs to its end without one."""
    crashes = {joint: random_episode_crashes(200614, 6, supervisor_joint_search=joint) for joint in (False, True)}
    assert crashes == {False: True, True: False}


def test_the_joint_search_checks_every_room_under_the_actions_the_passes_end_with():
    """The committed MA2C model of the merge grid (density 2, seed 1), greedy, held-out episode
    100287 with 4 AVs: the second pass brakes an AV whose follower was served earlier in that pass
    against its proposal, so the follower's room is stale and, served one at a time, it drives into
    the AV at step 95. The joint search takes every AV's room under the final actions and brakes it."""
    from sb3_marl.algos.common.policies import model_policy
    from sb3_marl.benchmark.trial_files import RUN_ID
    from sb3_marl.evaluation import run_episodes
    from sb3_marl.runs.folders import find_run

    trial = Path(__file__).parents[2] / "results" / "paper-grid" / "trials" / "ma2c_density2_merge_seed1"
    run = find_run(trial, "ma2c", MERGE_ENV_IDS[2], RUN_ID)
    policy = model_policy(run.load_model("cpu"), deterministic=True)
    crashes = {}
    for joint in (False, True):
        env = make(2, **{**run.env_config, "n_avs": 4, "safety_supervisor": True, "supervisor_joint_search": joint})
        crashes[joint] = run_episodes(env, policy, 1, seed=100287)[0].crashed
    assert crashes == {False: True, True: False}


def test_the_supervisor_releases_an_av_it_braked_when_braking_on_would_be_run_into():
    """Density 3, 5 AVs, random available meta-actions (episode 200523 of
    benchmarks/supervisor_safety.py): an AV braked to a stop behind a slow HDV has an HDV 1 m
    behind it; FASTER runs into the HDV ahead, braking on is run into from behind. The policy's mask
    has no SLOWER below the speed ladder, but the supervisor may choose it (the brake's release, to
    the ladder's lowest speed): it does, and the episode runs to its end (it crashed at step 92
    without the release)."""
    from sb3_marl.evaluation import run_episodes

    seed, masks, released = 200523, [], []
    rng = np.random.default_rng(seed)

    def policy(env, obs):
        masks.append(env.action_masks().copy())
        return np.array([rng.choice(np.flatnonzero(mask)) for mask in masks[-1]])

    def on_step(env, info):
        if info["step"] == 0:
            return
        executed = np.asarray(info["executed_action"])
        released.append(not masks[-1][executed == 4, 4].all())

    env = make(3, n_avs=5, safety_supervisor=True)
    assert supervisor_switches(env.config) == (True, True, False)
    episode = run_episodes(env, policy, 1, seed, on_step)[0]
    assert not episode.crashed and episode.length == 100 and any(released)


def test_mobil_safety_flags_a_merge_in_front_of_an_hdv_still_on_the_lane_before():
    """An AV on the merging lane at 15 m/s, an HDV at 23 m/s 20 m behind it on the main road's
    section before the merging lane: highway-env's IDM does not see the AV until it enters the
    section beside it, then would have to brake harder than its safe braking, so merging (LANE_LEFT)
    is flagged; with the HDV 80 m back it is not. Keeping the merging lane (IDLE) never is."""
    from sb3_marl.safety.rooms import unsafe_cut_ins
    from sb3_marl.sim.meta_actions import meta_action_targets

    env = make(1, n_avs=1, safety_supervisor=True)
    env.reset(seed=0)
    flagged = {}
    for behind in (20.0, 80.0):
        env.place([(330.0, MERGING_LANE, 15.0)], hdvs=[(330.0 - behind, MAIN_BEFORE, 23.0)])
        lanes = env.supervisor.horizon.lanes
        candidate_lane = meta_action_targets(env.state, 1, lanes, env.supervisor.horizon.ladder)[0]
        flagged[behind] = unsafe_cut_ins(env.state, 1, lanes, candidate_lane, env.config["speed_limit"])[0]
    assert flagged[20.0][0] and not flagged[80.0][0]  # LANE_LEFT
    assert not flagged[20.0][1] and not flagged[80.0][1]  # IDLE


def test_mobil_safety_avoids_a_crash_of_random_meta_actions():
    """Density 3, 5 AVs, random available meta-actions (episode 200563 of
    benchmarks/supervisor_safety.py, one of the two crashes the merge's supervisor leaves): an AV
    merges at 9 m/s 20 m in front of an HDV closing at 22 m/s, brakes for a slow queue and is run
    into at step 81; with ``supervisor_mobil_safety`` the merge waits and the episode runs to its end."""
    crashed = {check: random_episode_crashes(200563, 5, supervisor_mobil_safety=check) for check in (False, True)}
    assert crashed == {False: True, True: False} and not make(3).config["supervisor_mobil_safety"]


def test_merge_metrics_count_the_ramp_avs_that_merge():
    from sb3_marl.evaluation import run_episodes, summarize
    from sb3_marl.evaluation.baselines import IDMMobilPolicy

    summary = summarize(run_episodes(make(1, safety_supervisor=True), IDMMobilPolicy(), 10, seed=0))
    assert summary["merge_rate"] > 0.9 and 5.0 < summary["time_to_merge_mean"] < 20.0  # [s]
    assert summary["lane_changes_per_episode"] < 3  # following the road into the next section is not one
    assert "merge_rate" not in summarize(run_episodes(gym.make(ENV_IDS[1]).unwrapped, IDMMobilPolicy(), 1, seed=0))


def test_the_merge_columns_say_dash_where_a_mean_is_undefined():
    from sb3_marl.evaluation import MERGE_COLUMNS

    undefined = {"merge_rate": float("nan"), "time_to_merge_mean": float("nan"), "stranded_per_episode": 0.0}
    assert [fmt(undefined) for _, fmt in MERGE_COLUMNS] == ["-", "-", "0.00"]
    defined = {"merge_rate": 0.5, "time_to_merge_mean": 7.25, "stranded_per_episode": 1.5}
    assert [fmt(defined) for _, fmt in MERGE_COLUMNS] == ["0.500", "7.25", "1.50"]
