"""MA2C learns: after a short training on density 1 it clearly beats a uniformly random policy.

Both are scored under the paper's configuration and the authors' evaluation protocol (the zoo
config's scenario: safety supervisor on; MA2C's actions sampled from its masked policy; the
random policy draws among the available actions). Margins come from measurements on the 2-core
development machine with this budget (60k AV-steps, about 35 s of training): over these 60
episodes MA2C scored 17.7 ± 26.5 (collision rate 0.00) against -53.9 ± 41.3 (0.08) for the random
policy, a gap of 71; the test asks for 30.
"""

import numpy as np

from sb3_marl.algos.common.policies import model_policy
from sb3_marl.envs import ENV_IDS
from sb3_marl.evaluation import evaluate_on_density
from sb3_marl.runs.hyperparams import load_hyperparams
from sb3_marl.runs.training import make_model, make_venv

BUDGET = 60_000  # AV-steps
EPISODES = 60  # 20 per AV count (1, 2, 3), seeds 1000..1059


def masked_random_policy(seed: int):
    rng = np.random.default_rng(seed)
    return lambda env, obs: np.array([rng.choice(np.flatnonzero(row)) for row in env.action_masks()])


def test_ma2c_beats_random_after_a_short_training():
    hyperparams = load_hyperparams("ma2c", ENV_IDS[1])
    config = hyperparams["env_config"]
    assert config["safety_supervisor"]
    venv = make_venv(ENV_IDS[1], hyperparams, seed=0)
    model = make_model("ma2c", venv, hyperparams, seed=0)
    model.learn(BUDGET)
    venv.close()
    trained = evaluate_on_density(model_policy(model), ENV_IDS[1], EPISODES, seed=1000, config=config)
    random = evaluate_on_density(masked_random_policy(0), ENV_IDS[1], EPISODES, seed=1000, config=config)
    print(f"ma2c: {trained}\nrandom: {random}")
    assert trained["return_mean"] > random["return_mean"] + 30.0
