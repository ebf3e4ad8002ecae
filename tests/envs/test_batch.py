"""The batched step (:class:`~sb3_marl.envs.batch.RoadBatch`) gives the episodes of stepping the
scenario copies one by one: the same observations, rewards, masks, executed actions, events,
step arrays and infos, step by step, with the same seeds."""

from __future__ import annotations

import copy
from dataclasses import fields

import numpy as np
import pytest

from sb3_marl.envs import ENV_IDS, MERGE_ENV_IDS, make_scenario
from wrappers import ParameterSharingVecEnv
from wrappers.step_arrays import StepArrays


def _trace(env_id: str, batched: bool, steps: int, config: dict, reward_mode: str = "local", **kwargs) -> list:
    """Everything the VecEnv returns over ``steps`` steps of random masked actions."""
    options = {"n_copies": 4, "reward_mode": reward_mode, "seed": 7, "config": config, "batched": batched}
    venv = ParameterSharingVecEnv(env_id, **options, **kwargs)
    assert (venv.batch is not None) == batched
    rng = np.random.default_rng(1)
    trace: list = [venv.reset(), venv.reset_infos, *_arrays(venv.step_arrays)]
    for _ in range(steps):
        masks = venv.action_masks()
        actions = np.array([rng.choice(np.flatnonzero(row)) for row in masks])
        obs, rewards, dones, infos = venv.step(actions)
        trace += [obs, rewards, dones, masks, venv.rule_actions(), *_arrays(venv.step_arrays)]
        for info in infos:
            assert set(info) in (set(), {"terminal_observation", "TimeLimit.truncated", "episode"})
            if "terminal_observation" in info:
                episode = info["episode"]
                trace += [info["terminal_observation"], info["TimeLimit.truncated"], episode["r"], episode["l"]]
    venv.close()
    return trace


def _arrays(arrays: StepArrays) -> list:
    """Every field of a step's arrays (each reward term by name)."""
    values = [getattr(arrays, f.name) for f in fields(arrays) if f.name != "reward_terms"]
    return [*values, sorted(arrays.reward_terms), *arrays.reward_terms.values()]


def _assert_same(batched: list, one_by_one: list) -> None:
    assert len(batched) == len(one_by_one)
    for step, (a, b) in enumerate(zip(batched, one_by_one)):
        if isinstance(a, np.ndarray):
            assert a.dtype == b.dtype and np.array_equal(a, b), step
        else:
            assert repr(a) == repr(b), step  # types and values, bit for bit


@pytest.mark.parametrize("env_id", [*ENV_IDS.values(), *MERGE_ENV_IDS.values()])
@pytest.mark.parametrize("supervisor", [False, True])
def test_batched_episodes_equal_one_by_one(env_id, supervisor):
    config = {"safety_supervisor": supervisor}
    batched, one_by_one = (_trace(env_id, flag, 120, config) for flag in (True, False))
    ends = sum(1 for item in batched if isinstance(item, np.ndarray) and item.dtype == bool and item.ndim == 1 and item.any())
    assert ends > 0  # episodes ended (crashes or the road's end) and copies were reset in between
    _assert_same(batched, one_by_one)


@pytest.mark.parametrize(
    ("config", "options"),
    [
        ({"supervisor_shadow": True, "obs_target_speed": True}, {"reward_mode": "global"}),
        ({"safety_supervisor": True}, {"supervisor_dropout": 0.5, "reward_mode": "individual"}),
    ],
)
def test_batched_options_equal_one_by_one(config, options):
    """Shadow mode, the target-speed column, the per-episode supervisor dropout, the reward modes."""
    batched, one_by_one = (_trace(ENV_IDS[2], flag, 80, config, **options) for flag in (True, False))
    _assert_same(batched, one_by_one)


def test_the_copies_envs_follow_the_batch():
    """A copy's env reads its road in the batch's state; what the env changes is the batch's."""
    venv = ParameterSharingVecEnv(ENV_IDS[1], n_copies=2, seed=0)
    venv.reset()
    for _ in range(3):
        venv.step(np.ones(venv.num_envs, dtype=np.int64))
    env = venv.copy_env(0)
    assert env.steps_done == venv.batch.copies.steps[0]
    assert np.shares_memory(env.state, venv.batch.roads.states)  # a view of the batch's roads, not a copy
    env.place(avs=[(100.0 + 40 * i, 0, 25.0) for i in range(env.n_avs)])
    venv.step(np.ones(venv.num_envs, dtype=np.int64))
    x = venv.copy_env(0).state[: env.n_avs, 0]
    assert np.allclose(x, 100.0 + 40 * np.arange(env.n_avs) + 25.0 / 5, atol=0.5)  # one policy step from the placed AVs
    venv.close()


def test_the_merge_keeps_its_merge_times_in_a_batch():
    """The merge's ramp AVs and merge times, which its env's info reports, follow the batch."""
    venv = ParameterSharingVecEnv(MERGE_ENV_IDS[1], n_copies=3, seed=0, config={"safety_supervisor": True})
    venv.reset()
    for _ in range(60):
        venv.step(np.full(venv.num_envs, 1, dtype=np.int64))  # IDLE: the supervisor takes the ramp AVs across
    assert venv.batch.roads.ramp_av.any() and np.isfinite(venv.batch.roads.merge_time).any()
    for k in range(venv.n_copies):  # each copy's env reads its record there
        env = venv.copy_env(k)
        assert env._roads is venv.batch.roads and env._roads.slots(env._k) == venv.slices[k]
    venv.close()


@pytest.mark.parametrize("options", [{"batched": False}, {"render_mode": "rgb_array"}, {"vec_backend": "subproc"}])
def test_what_steps_one_by_one(options):
    venv = ParameterSharingVecEnv(ENV_IDS[1], n_copies=2, **options)
    assert venv.batch is None
    venv.close()


def test_envs_after_batched_new_episodes_equal_one_by_one():
    """Episodes begun inside the compiled step leave each copy's env (read between steps) as its
    own resets would: the same generator states, HDV counts, clocks and supervisor draws."""
    config, options = {"safety_supervisor": True}, {"n_copies": 3, "seed": 3, "supervisor_dropout": 0.5}
    venvs = [ParameterSharingVecEnv(ENV_IDS[3], config=config, batched=flag, **options) for flag in (True, False)]
    rng = np.random.default_rng(0)
    ended = 0
    for venv in venvs:
        venv.reset()
    for _ in range(40):
        actions = rng.integers(0, 5, venvs[0].num_envs)
        ended += int(venvs[0].step(actions)[2].sum())
        venvs[1].step(actions)
    assert ended > 0
    for k in range(3):
        batched, one_by_one = (venv.copy_env(k) for venv in venvs)
        for name in ("n_hdvs", "time", "steps"):
            assert getattr(batched, name) == getattr(one_by_one, name), name
        assert batched.supervised == one_by_one.supervised
        assert batched.np_random.bit_generator.state == one_by_one.np_random.bit_generator.state
        dropout_words = [env._roads.copies.dropout_generators[env._k] for env in (batched, one_by_one)]
        np.testing.assert_array_equal(*dropout_words)
        np.testing.assert_array_equal(batched.state, one_by_one.state)
    for venv in venvs:
        venv.close()


def test_np_random_is_the_stream_the_episodes_are_drawn_from():
    """Draws through ``env.np_random`` (read once or again) advance the words the next spawn draws
    from, alone and after a change of the AV count."""
    env = make_scenario(ENV_IDS[1], {"n_avs": 1})
    env.reset(seed=0)
    assert env.np_random.random() != env.np_random.random()
    for change in ({}, {"n_avs": 2}):
        starts = []
        for draw in (True, False):
            env.reset(seed=5)
            if draw:
                env.np_random.random()
            env.configure(change)
            starts.append(env.reset()[0])
        assert not np.array_equal(*starts), change


def test_a_batched_copy_shows_each_step_and_refuses_a_new_av_count_untouched():
    venv = ParameterSharingVecEnv(ENV_IDS[1], n_copies=2, seed=0, config={"safety_supervisor": True}, supervisor_dropout=1.0)
    venv.reset()
    env = venv.copy_env(0)
    before = env.road.vehicles[0].position[0]
    venv.step(np.ones(venv.num_envs, dtype=np.int64))
    assert env.road.vehicles[0].position[0] != before and env.road.vehicles[0].position[0] == env.state[0, 0]
    n = env.n_avs
    with pytest.raises(RuntimeError, match="cannot change n_avs"):
        venv.env_method("configure", {"n_avs": n + 1}, indices=[0])
    assert env.n_avs == env.config["n_avs"] == n and env.action_masks().shape == (n, 5)
    assert not env.supervised  # the dropout's draw (p = 1) outlives a configure that does not set the supervisor
    env.configure({})
    assert not env.supervised
    env.configure({"safety_supervisor": True})
    assert env.supervised
    venv.close()


def test_a_deep_copy_of_a_batched_copy_steps_alone_as_one_stepped_alone():
    """``copy.deepcopy`` of a batch's copy (highway-env's planners copy the env) steps alone, as a
    deep copy of the same copy stepped one by one does, and leaves the batch as it was."""
    venvs = [ParameterSharingVecEnv(ENV_IDS[2], n_copies=2, seed=4, batched=flag) for flag in (True, False)]
    rng = np.random.default_rng(1)
    for venv in venvs:
        venv.reset()
    for _ in range(3):
        actions = rng.integers(0, 5, venvs[0].num_envs)
        for venv in venvs:
            venv.step(actions)
    batch_states = venvs[0].batch.roads.states.copy()
    copies = [copy.deepcopy(venv.copy_env(1)) for venv in venvs]
    assert not copies[0]._roads.batched and copies[0]._roads is not venvs[0].batch.roads
    for _ in range(5):
        actions = rng.integers(0, 5, copies[0].n_avs)
        steps = [env.step(actions) for env in copies]
        np.testing.assert_array_equal(steps[0][0], steps[1][0])
        assert steps[0][1:4] == steps[1][1:4]
        if steps[0][2] or steps[0][3]:
            break
    np.testing.assert_array_equal(venvs[0].batch.roads.states, batch_states)
    assert copies[0].np_random.bit_generator.state == copies[1].np_random.bit_generator.state
    for venv in venvs:
        venv.close()
