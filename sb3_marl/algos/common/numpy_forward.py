"""The shared policy's forward pass in numpy for rollouts (:class:`NumpyActorCritic`).

Torch pays 5–15 µs per operation whatever the batch, so on the few dozen AV slots of one VecEnv
step a torch forward of the MA2C network costs several times a numpy one. During rollouts the
actor-critic's forward (features, heads, masked softmax, sampling, values) runs here, on views of
the torch parameters (``param.detach().numpy()`` shares their memory: every optimiser step is seen
at once, nothing is copied); torch does the updates. The modules understood are those of the
project's policies: the MA2C network (:class:`~sb3_marl.algos.common.policies.MA2CFeaturesExtractor`),
SB3's flatten extractor, the centralised critic's extractors, and ``nn.Sequential`` stacks of
``Linear``, ``ReLU``, ``Tanh`` and ``Flatten``; :meth:`NumpyActorCritic.of` answers None for any
other policy, which then keeps torch's forward. Probabilities and values equal torch's to 1e-6
(tests/learners/test_numpy_forward.py). The layers compute in float64 (numpy's BLAS, whose kernels
differ by CPU in the last bits); the rollout stores values and log-probabilities as float32, as
SB3's buffer does, so such differences reach training only where a value lies within a few float64
ulps of a float32 rounding boundary (about 1e-8 of the values), and an action only where its draw
lies within them of a cumulative probability.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from sb3_contrib.common.maskable.policies import MaskableActorCriticPolicy
from stable_baselines3.common.preprocessing import is_image_space
from stable_baselines3.common.torch_layers import FlattenExtractor
from torch import nn

from sb3_marl.algos.common.policies import GlobalStateExtractor, LocalViewExtractor, MA2CFeaturesExtractor
from sb3_marl.envs.observation import LOCAL_KEY, STATE_KEY

Layer = Callable[[np.ndarray], np.ndarray]
#: sb3-contrib's logit of an unavailable action (``MaskableCategorical``'s HUGE_NEG)
MASKED_LOGIT = -1e8


class Unsupported(Exception):
    """A module without a numpy twin here: the policy keeps torch's forward."""


def _sequential(module: nn.Module) -> Layer:
    """A numpy function of an ``nn.Sequential`` (or one layer) of Linear / ReLU / Tanh / Flatten."""
    layers = list(module) if isinstance(module, nn.Sequential) else [module]
    steps: list[Layer] = []
    for layer in layers:
        if isinstance(layer, nn.Linear):
            steps.append(_linear(layer))
        elif isinstance(layer, nn.ReLU):
            steps.append(lambda x: np.maximum(x, 0.0))
        elif isinstance(layer, nn.Tanh):
            steps.append(np.tanh)
        elif isinstance(layer, nn.Flatten) and layer.start_dim == 1 and layer.end_dim == -1:
            steps.append(lambda x: x.reshape(len(x), -1))
        else:
            raise Unsupported(type(layer).__name__)

    def forward(x: np.ndarray) -> np.ndarray:
        for step in steps:
            x = step(x)
        return x

    return forward


def _linear(layer: nn.Linear) -> Layer:
    """``x @ W.T + b`` on views of the layer's weight and bias."""
    weight = layer.weight.detach().numpy()
    bias = None if layer.bias is None else layer.bias.detach().numpy()
    if bias is None:
        return lambda x: x @ weight.T
    return lambda x: x @ weight.T + bias


def _extractor(module: nn.Module) -> Callable[[Any], np.ndarray]:
    """A numpy function of a features extractor of the project's policies."""
    if isinstance(module, MA2CFeaturesExtractor):
        units = [(columns, _sequential(module.units[unit])) for unit, columns in module.columns.items()]
        trunk = _sequential(module.trunk)

        def ma2c(obs: np.ndarray) -> np.ndarray:
            parts = [layer(obs[:, :, columns].reshape(len(obs), -1)) for columns, layer in units]
            return trunk(np.concatenate(parts, axis=1))

        return ma2c
    if isinstance(module, FlattenExtractor):
        return lambda obs: obs.reshape(len(obs), -1)
    if isinstance(module, LocalViewExtractor):
        local = _extractor(module.local)
        return lambda obs: local(obs[LOCAL_KEY])
    if isinstance(module, GlobalStateExtractor):
        net = _sequential(module.net)
        return lambda obs: net(obs[STATE_KEY])
    raise Unsupported(type(module).__name__)


class NumpyActorCritic:
    """The forward pass of a maskable actor-critic policy in numpy (see the module doc).

    :param policy: sb3-contrib's ``MaskableActorCriticPolicy`` (or a subclass) on CPU, Discrete actions
    """

    def __init__(self, policy: MaskableActorCriticPolicy) -> None:
        if policy.share_features_extractor:
            actor_features = critic_features = _extractor(policy.features_extractor)
        else:
            actor_features, critic_features = (
                _extractor(policy.pi_features_extractor),
                _extractor(policy.vf_features_extractor),
            )
        actor, critic = _sequential(policy.mlp_extractor.policy_net), _sequential(policy.mlp_extractor.value_net)
        action_net, value_net = _sequential(policy.action_net), _sequential(policy.value_net)
        self._shared = policy.share_features_extractor
        self._actor = lambda features: action_net(actor(features))
        self._critic = lambda features: value_net(critic(features))
        self._actor_features, self._critic_features = actor_features, critic_features

    @classmethod
    def of(cls, policy: Any) -> NumpyActorCritic | None:
        """The numpy forward of ``policy``, or None where a module has no numpy twin here (or the
        policy is not a maskable actor-critic on the CPU with one discrete action per slot)."""
        if not isinstance(policy, MaskableActorCriticPolicy) or policy.device.type != "cpu":
            return None
        if getattr(policy.action_space, "n", None) is None or _has_images(policy):
            return None
        try:
            return cls(policy)
        except Unsupported:
            return None

    def __call__(
        self, obs: Any, masks: np.ndarray | None, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Actions sampled from the masked policy (int64 (batch,)), values (float64 (batch,)) and
        the actions' log-probabilities (float64 (batch,)) of observations ``obs`` (an array, or a
        dict of arrays, batch first) under ``masks`` ((batch, actions) bool; None: all
        available); the uniform draws come from ``rng`` (one per row)."""
        obs = _float64(obs)
        features = self._actor_features(obs)
        log_probs = self._log_probs(features, masks)
        cumulative = np.cumsum(np.exp(log_probs), axis=1)
        cumulative /= cumulative[:, -1:]  # the last entry exactly 1: every draw below it
        actions = (cumulative <= rng.random(len(log_probs))[:, None]).sum(axis=1)
        rows = np.arange(len(actions))
        return actions, self._values(obs, features), log_probs[rows, actions]

    def probabilities(self, obs: Any, masks: np.ndarray | None) -> np.ndarray:
        """(batch, actions) the masked policy's action probabilities (for tests and diagnostics)."""
        return np.exp(self._log_probs(self._actor_features(_float64(obs)), masks))

    def values(self, obs: Any) -> np.ndarray:
        """(batch,) float64 the critic's values of observations ``obs``."""
        return self._values(_float64(obs), None)

    def _log_probs(self, actor_features: np.ndarray, masks: np.ndarray | None) -> np.ndarray:
        """(batch, actions) the masked policy's log-probabilities from the actor's features."""
        logits = self._actor(actor_features)
        if masks is not None:
            logits = np.where(masks, logits, MASKED_LOGIT)
        return logits - _logsumexp(logits)

    def _values(self, obs: Any, actor_features: np.ndarray | None) -> np.ndarray:
        """(batch,) the critic's values of float64 observations ``obs``; with a shared extractor it
        reads ``actor_features`` where the caller has them already."""
        if not self._shared:
            return self._critic(self._critic_features(obs))[:, 0]
        return self._critic(self._actor_features(obs) if actor_features is None else actor_features)[:, 0]


def _logsumexp(logits: np.ndarray) -> np.ndarray:
    top = logits.max(axis=1, keepdims=True)
    return top + np.log(np.exp(logits - top).sum(axis=1, keepdims=True))


def _float64(obs: Any) -> Any:
    """Observations as float64 arrays: the layers compute in double precision on the float32
    weights, so the results differ from torch's only by torch's own float32 rounding."""
    if isinstance(obs, dict):
        return {key: np.asarray(value, dtype=np.float64) for key, value in obs.items()}
    return np.asarray(obs, dtype=np.float64)


def _has_images(policy: Any) -> bool:
    """Whether any observation is an image (SB3 would rescale it: left to torch)."""
    spaces = getattr(policy.observation_space, "spaces", {"": policy.observation_space})
    return any(is_image_space(space) for space in spaces.values())
