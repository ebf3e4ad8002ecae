"""The rollouts' numpy forward (:mod:`sb3_marl.algos.common.numpy_forward`) equals the torch
policy's: action probabilities and values for random weights and masks, every actor-critic layout
the learners build; its seeded sampling repeats and never picks an unavailable action."""

from __future__ import annotations

import numpy as np
import pytest
import torch as th

from sb3_marl.algos.common.numpy_forward import NumpyActorCritic
from sb3_marl.envs import ENV_IDS
from sb3_marl.runs.hyperparams import load_hyperparams
from sb3_marl.runs.training import make_model, make_venv

LAYOUTS = {
    "shared MA2C network": {"architecture": "shared"},
    "separate MA2C networks": {"architecture": "separate"},
    "centralised critic": {"architecture": "separate", "critic": "centralised"},
    "SB3's MLP": {"policy_kwargs": {"net_arch": [32, 16]}},
}


def _model(layout: dict, algo: str = "ma2c"):
    hyperparams = {**load_hyperparams(algo, ENV_IDS[2]), "n_steps": 8, **layout}
    if layout.get("policy_kwargs"):
        hyperparams.pop("architecture", None)
    venv = make_venv(ENV_IDS[2], hyperparams, seed=0)
    model = make_model(algo, venv, hyperparams, seed=0)
    with th.no_grad():  # random weights far from the initialisation's (orthogonal, small heads)
        for parameter in model.policy.parameters():
            parameter.normal_(0.0, 0.1)
    return model, venv


def _torch(policy, obs, masks) -> tuple[np.ndarray, np.ndarray]:
    """The torch policy's action probabilities and values."""
    tensors = policy.obs_to_tensor(obs)[0]
    with th.no_grad():
        probs = policy.get_distribution(tensors, action_masks=masks).distribution.probs.numpy()
        return probs, policy.predict_values(tensors).numpy()[:, 0]


@pytest.mark.parametrize("layout", LAYOUTS.values(), ids=LAYOUTS.keys())
def test_probabilities_and_values_equal_torch(layout):
    """To 1e-6 (the numpy layers compute in double precision on the float32 weights)."""
    model, venv = _model(layout)
    forward = NumpyActorCritic.of(model.policy)
    assert forward is not None
    rng = np.random.default_rng(0)
    obs = venv.reset()
    for _ in range(3):
        masks = rng.random((venv.num_envs, 5)) < 0.6
        masks[np.arange(venv.num_envs), rng.integers(0, 5, venv.num_envs)] = True  # one available at least
        probs, values = _torch(model.policy, obs, masks)
        np.testing.assert_allclose(forward.probabilities(obs, masks), probs, rtol=0, atol=1e-6)
        np.testing.assert_allclose(forward.values(obs), values, rtol=0, atol=1e-6)
        actions, sampled_values, log_probs = forward(obs, masks, np.random.default_rng(1))
        np.testing.assert_array_equal(sampled_values, forward.values(obs))
        np.testing.assert_allclose(np.exp(log_probs), probs[np.arange(len(actions)), actions], rtol=1e-5, atol=1e-7)
        obs = venv.step(actions)[0]
    venv.close()


def test_seeded_sampling_repeats_and_follows_the_masked_probabilities():
    model, venv = _model(LAYOUTS["shared MA2C network"])
    forward = NumpyActorCritic.of(model.policy)
    obs = np.repeat(venv.reset()[:1], 20_000, axis=0)
    masks = np.tile([True, False, True, True, False], (len(obs), 1))
    first, again = (forward(obs, masks, np.random.default_rng(5))[0] for _ in range(2))
    np.testing.assert_array_equal(first, again)
    shares = np.bincount(first, minlength=5) / len(first)
    assert shares[1] == shares[4] == 0.0
    np.testing.assert_allclose(shares, forward.probabilities(obs[:1], masks[:1])[0], atol=0.015)
    venv.close()


def test_the_numpy_forward_follows_every_optimiser_step():
    """It reads the torch parameters' memory: an update is seen without rebuilding it."""
    model, venv = _model(LAYOUTS["shared MA2C network"])
    forward = NumpyActorCritic.of(model.policy)
    obs = venv.reset()
    before = forward.values(obs).copy()
    model.learn(16 * venv.num_envs)
    with th.no_grad():
        values = model.policy.predict_values(model.policy.obs_to_tensor(obs)[0]).numpy()[:, 0]
    assert not np.allclose(before, values)
    np.testing.assert_allclose(forward.values(obs), values, rtol=1e-6, atol=1e-6)
    venv.close()
