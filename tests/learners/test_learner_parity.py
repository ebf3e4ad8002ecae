"""What the learners learn from the same seeds does not change when their code is made faster:
every learner (zoo config, seed 0) trains a few thousand AV-steps, and each of its parameter
tensors must match the fingerprint in ``learner_parameters.json`` (written by the code before the
learners' speed work, issue 54) to float tolerance.

Rewrite the reference only for a change that is meant to change learning, and say so in the changelog:

    python tests/learners/test_learner_parity.py --write
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch as th

from sb3_marl.algos.common.policies import unchecked_distributions
from sb3_marl.envs import ENV_IDS
from sb3_marl.runs.hyperparams import load_hyperparams, merge_hyperparams
from sb3_marl.runs.training import make_model, make_venv

REFERENCE = Path(__file__).with_name("learner_parameters.json")
AV_STEPS = 3_000
LEARNERS = ("ma2c", "mappo", "madqn", "maacktr", "matrpo")
#: name -> (algorithm, density, overrides of its zoo config): every learner, and the extra terms
#: that have their own optimiser steps or clipping (the supervisor teacher's, the rule prior's)
CASES: dict[str, tuple[str, int, dict]] = {
    **{f"{algo}-d{density}": (algo, density, {}) for algo in LEARNERS for density in (1, 3)},
    "ma2c-d1-teacher": ("ma2c", 1, {"safety_loss_coef": 0.5}),
    "ma2c-d1-prior": ("ma2c", 1, {"prior": "idm-mobil", "prior_warm_start": 500, "prior_decay_steps": 2_000}),
    "madqn-d1-teacher-prior": ("madqn", 1, {"safety_loss_coef": 0.5, "prior": "idm-mobil", "prior_decay_steps": 2_000}),
}
#: Float tolerance: the same code on another CPU's vector units (AVX2 against AVX-512) ends 3,000
#: AV-steps up to ~2e-4 apart relative, 2e-4 absolute on small biases; a change in what is learned
#: moves them by far more.
RTOL, ATOL = 1e-3, 1e-3


def fingerprint(case: str) -> dict[str, list[float]]:
    """Per parameter tensor of the trained policy: its sum, its L2 norm and its dot product with a
    fixed random vector."""
    algo, density, overrides = CASES[case]
    env_id = ENV_IDS[density]
    hyperparams = merge_hyperparams(load_hyperparams(algo, env_id), overrides)
    venv = make_venv(env_id, hyperparams, seed=0)
    try:
        model = make_model(algo, venv, hyperparams, seed=0)
        with unchecked_distributions():
            model.learn(AV_STEPS)
    finally:
        venv.close()
    found = {}
    for name, tensor in model.policy.state_dict().items():
        values = tensor.detach().double().flatten().numpy()
        probe = np.random.default_rng(len(name)).standard_normal(values.size)
        found[name] = [float(values.sum()), float(np.linalg.norm(values)), float(values @ probe)]
    return found


@pytest.mark.parametrize("case", sorted(CASES))
def test_the_learners_learn_what_they_learned_before(case):
    reference = json.loads(REFERENCE.read_text())["cases"][case]
    found = fingerprint(case)
    assert sorted(found) == sorted(reference)
    for name, values in reference.items():
        np.testing.assert_allclose(found[name], values, rtol=RTOL, atol=ATOL, err_msg=f"{case}: {name}")


def write_reference() -> None:
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=True).stdout
    th.set_num_threads(1)
    cases = {case: fingerprint(case) for case in sorted(CASES)}
    text = json.dumps({"commit": commit.strip(), "av_steps": AV_STEPS, "cases": cases}, indent=1) + "\n"
    REFERENCE.write_text(text)


if __name__ == "__main__" and sys.argv[1:] == ["--write"]:
    write_reference()
