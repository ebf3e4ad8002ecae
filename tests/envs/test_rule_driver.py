"""The compiled rule driver (IDM + MOBIL as meta-actions) against highway-env's own objects."""

import numpy as np
import pytest

from sb3_marl.envs import ENV_IDS, make_scenario
from sb3_marl.envs.lane_change_env import ACTION_INDEX
from sb3_marl.evaluation.baselines import IDMMobilPolicy
from tests.envs.parity import ACTION_PROBABILITIES, stock_rule_actions


@pytest.mark.parametrize("density", [1, 2, 3])
@pytest.mark.parametrize("politeness", [0.0, 1.0])
def test_rule_driver_matches_highway_env_objects(density, politeness):
    """Every step of seeded episodes (mostly IDLE, some lane and speed changes, so that AVs meet
    slower leaders and free lanes; the supervisor on, so that dense episodes last): the compiled
    rule actions equal the object-based decision, and the step's info reports them for the state
    it returns."""
    env = make_scenario(ENV_IDS[density], {"hdv_politeness": politeness, "safety_supervisor": True})
    rng = np.random.default_rng(density)
    checked, kinds = 0, set()
    for seed in range(8):
        _, info = env.reset(seed=seed)
        done = False
        while not done:
            expected = stock_rule_actions(env)
            np.testing.assert_array_equal(env.rule_actions(), expected)
            np.testing.assert_array_equal(info["rule_action"], expected)
            kinds.update(expected.tolist())
            checked += 1
            actions = rng.choice(5, size=env.n_avs, p=ACTION_PROBABILITIES["cruise"])
            _, _, terminated, truncated, info = env.step(actions)
            done = terminated or truncated
    assert checked > 300
    assert {ACTION_INDEX["IDLE"], ACTION_INDEX["FASTER"], ACTION_INDEX["SLOWER"]} <= kinds


def test_rule_driver_brakes_behind_a_slower_leader():
    """An AV at 30 m/s 25 m behind a 15 m/s leader, the other lane blocked beside it: SLOWER."""
    env = make_scenario(ENV_IDS[1], {"n_avs": 1})
    env.reset(seed=0)
    _, info = env.place([(100.0, 0, 30.0)], [(125.0, 0, 15.0), (100.0 - 8.0, 1, 30.0), (110.0, 1, 30.0)])
    assert env.rule_actions().tolist() == [ACTION_INDEX["SLOWER"]] == info["rule_action"].tolist()
    np.testing.assert_array_equal(IDMMobilPolicy()(env, None), env.rule_actions())
