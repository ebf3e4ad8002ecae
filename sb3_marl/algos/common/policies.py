"""The MA2C network of the paper as SB3 feature extractors and policy presets.

Observations are (vehicles, features) matrices with features (presence, x, y, vx, vy). The paper
splits the inputs by physical unit: presence, positions (x, y) and velocities (vx, vy) each go
through their own fully connected layer (32, 64 and 64 units in the MARL_CAVs code), the three
are concatenated and go through a 128-unit layer, the trunk, on which the actor and critic heads sit.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING, Any

import numpy as np
import torch as th
from gymnasium import spaces
from sb3_contrib.common.maskable.policies import MaskableActorCriticPolicy
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn

from sb3_marl.envs.observation import LOCAL_KEY, STATE_KEY, centralised_observations

if TYPE_CHECKING:
    from sb3_marl.envs.lane_change_env import LaneChangeEnv
    from sb3_marl.evaluation.episodes import Policy

#: Actor-critic network layouts: one trunk for both heads (the paper's) or one network each.
ARCHITECTURES = ("shared", "separate")
#: Feature columns of each physical unit in the scenario's observation (slices: views, no copies);
#: the optional 6th feature, the ego's target speed [m/s], is a velocity.
UNIT_COLUMNS = {"presence": slice(0, 1), "position": slice(1, 3), "velocity": slice(3, 5)}
UNIT_COLUMNS_WITH_TARGET_SPEED = {**UNIT_COLUMNS, "velocity": slice(3, 6)}


class MA2CFeaturesExtractor(BaseFeaturesExtractor):
    """Inputs split by physical unit, one FC layer each, concatenated, then a ``features_dim`` FC layer.

    :param observation_space: Box of shape (vehicles, 5), or (vehicles, 6) with the target speed
    :param unit_dims: output units of the presence, position and velocity layers
    :param features_dim: units of the trunk layer (128 in the paper)
    """

    def __init__(
        self,
        observation_space: spaces.Box,
        unit_dims: tuple[int, int, int] = (32, 64, 64),
        features_dim: int = 128,
    ) -> None:
        if len(observation_space.shape) != 2 or observation_space.shape[1] not in (5, 6):
            raise ValueError(
                f"MA2CFeaturesExtractor needs observations of shape (vehicles, 5) with features "
                f"(presence, x, y, vx, vy), or (vehicles, 6) with the target speed, got {observation_space.shape}."
            )
        super().__init__(observation_space, features_dim)
        vehicles = observation_space.shape[0]
        self.columns = UNIT_COLUMNS if observation_space.shape[1] == 5 else UNIT_COLUMNS_WITH_TARGET_SPEED
        self.units = nn.ModuleDict(
            {
                unit: nn.Sequential(nn.Linear(vehicles * (columns.stop - columns.start), dim), nn.ReLU())
                for (unit, columns), dim in zip(self.columns.items(), unit_dims)
            }
        )
        self.trunk = nn.Sequential(nn.Linear(sum(unit_dims), features_dim), nn.ReLU())

    def forward(self, observations: th.Tensor) -> th.Tensor:
        parts = [layer(observations[:, :, self.columns[unit]].flatten(start_dim=1)) for unit, layer in self.units.items()]
        return self.trunk(th.cat(parts, dim=1))


class LocalViewExtractor(BaseFeaturesExtractor):
    """The MA2C network (:class:`MA2CFeaturesExtractor`) on the ``observation`` part of a
    centralised-critic Dict observation: the actor of CTDE sees only its AV's view."""

    def __init__(self, observation_space: spaces.Dict, **kwargs: Any) -> None:
        local = MA2CFeaturesExtractor(observation_space[LOCAL_KEY], **kwargs)  # type: ignore[arg-type]
        super().__init__(observation_space, local.features_dim)
        self.local = local

    def forward(self, observations: dict[str, th.Tensor]) -> th.Tensor:
        return self.local(observations[LOCAL_KEY])


class GlobalStateExtractor(BaseFeaturesExtractor):
    """The centralised critic's network: the copy's global state (``state``: one row per AV slot,
    presence and ego flags then the AV's view; :func:`~sb3_marl.envs.observation.centralised_observations`)
    flattened, then two fully connected ReLU layers (``hidden_dim``, then ``features_dim`` units)."""

    def __init__(self, observation_space: spaces.Dict, hidden_dim: int = 256, features_dim: int = 128) -> None:
        super().__init__(observation_space, features_dim)
        state_size = int(th.tensor(observation_space[STATE_KEY].shape).prod())
        self.net = nn.Sequential(
            nn.Flatten(), nn.Linear(state_size, hidden_dim), nn.ReLU(), nn.Linear(hidden_dim, features_dim), nn.ReLU()
        )

    def forward(self, observations: dict[str, th.Tensor]) -> th.Tensor:
        return self.net(observations[STATE_KEY])


class CentralisedCriticPolicy(MaskableActorCriticPolicy):
    """Maskable actor-critic policy with a centralised critic (CTDE): the actor's features come from
    ``features_extractor_class`` (default :class:`LocalViewExtractor`: the AV's own view), the
    critic's from ``critic_extractor_class`` (default :class:`GlobalStateExtractor`: the copy's
    global state). Acting needs only the actor; the critic trains it. Observations are the Dict of
    :class:`~wrappers.VecCentralisedState`.

    :param critic_extractor_class: features extractor of the critic
    :param critic_extractor_kwargs: its keyword arguments
    Other parameters: as sb3-contrib's ``MaskableActorCriticPolicy`` (``share_features_extractor``
    is always False: actor and critic read different inputs).
    """

    def __init__(
        self,
        *args: Any,
        features_extractor_class: type[BaseFeaturesExtractor] = LocalViewExtractor,
        critic_extractor_class: type[BaseFeaturesExtractor] = GlobalStateExtractor,
        critic_extractor_kwargs: dict[str, Any] | None = None,
        share_features_extractor: bool = False,
        **kwargs: Any,
    ) -> None:
        if share_features_extractor:
            raise ValueError(
                "CentralisedCriticPolicy: share_features_extractor must be False "
                "(the actor reads the AV's view, the critic the global state)."
            )
        self.critic_extractor_class = critic_extractor_class
        self.critic_extractor_kwargs = dict(critic_extractor_kwargs or {})
        super().__init__(  # type: ignore[misc]
            *args, features_extractor_class=features_extractor_class, share_features_extractor=False, **kwargs
        )

    def _build_mlp_extractor(self) -> None:
        # called by _build before the optimiser is created: the critic's extractor replaces the
        # second copy of the actor's that the parent built
        self.vf_features_extractor = self.critic_extractor_class(self.observation_space, **self.critic_extractor_kwargs)
        if self.vf_features_extractor.features_dim != self.features_dim:
            raise ValueError(
                f"The critic's features_dim {self.vf_features_extractor.features_dim} must equal the "
                f"actor's {self.features_dim} (one MLP extractor serves both)."
            )
        super()._build_mlp_extractor()

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(critic_extractor_class=self.critic_extractor_class, critic_extractor_kwargs=self.critic_extractor_kwargs)
        return data


def ma2c_policy_kwargs(architecture: str = "shared") -> dict[str, Any]:
    """``policy_kwargs`` for SB3 actor-critic algorithms (A2C, PPO, TRPO, MaskablePPO).

    :param architecture: ``shared`` (the paper's: one trunk for actor and critic) or ``separate``
        (distinct actor and critic networks, for the paper's ablation)
    """
    if architecture not in ARCHITECTURES:
        raise ValueError(f"Invalid architecture={architecture!r}: expected one of {list(ARCHITECTURES)}.")
    return {
        "features_extractor_class": MA2CFeaturesExtractor,
        "share_features_extractor": architecture == "shared",
        "net_arch": [],  # the heads sit directly on the 128-unit trunk
    }


#: SB3's Adam settings for actor-critic policies (eps 1e-5) with the fused kernel: one call per
#: optimiser step instead of a handful of tensor operations per parameter (a few % of MAPPO's
#: training time on one CPU core); the same algorithm.
ACTOR_CRITIC_FUSED_ADAM: dict[str, Any] = {"eps": 1e-5, "fused": True}


def ma2c_q_policy_kwargs() -> dict[str, Any]:
    """``policy_kwargs`` for DQN: the same network with a Q-value head, and Adam's fused kernel
    (one call per step instead of a handful of tensor operations per parameter: a gradient step of
    batch 128 takes 16–27 % less time on one CPU core; same algorithm, DQN's default Adam settings)."""
    return {"features_extractor_class": MA2CFeaturesExtractor, "net_arch": [], "optimizer_kwargs": {"fused": True}}


@contextmanager
def unchecked_distributions() -> Iterator[None]:
    """Skip ``torch.distributions``' argument checks inside the block, as ``python -O`` does.

    SB3 builds a fresh ``Categorical`` on every policy call; on the batch of a few AVs of one
    VecEnv step, its argument checks cost as much as the whole network (about 0.4 ms of 0.9 ms on
    a 2-core VM). Results are unchanged: invalid (NaN) logits still fail, in the sampling.
    """
    checked = th.distributions.Distribution._validate_args
    th.distributions.Distribution.set_default_validate_args(False)
    try:
        yield
    finally:
        th.distributions.Distribution.set_default_validate_args(checked)


def clip_gradients(optimizer: th.optim.Optimizer, max_norm: float) -> th.Tensor:
    """SB3's ``clip_grad_norm_(policy.parameters(), max_norm)`` over the parameters that ``optimizer``
    steps (a policy's others, as a DQN's target network, have no gradients), in one foreach pass and
    without walking the module tree on every update: the same norm and the same gradients."""
    parameters = [p for group in optimizer.param_groups for p in group["params"]]
    return th.nn.utils.clip_grad_norm_(parameters, max_norm, foreach=True)


#: The widest layer [units] and the most layer sizes a policy's ``policy_kwargs`` may name (the
#: paper's network: 32 / 64 / 64 and 128 units): a small file cannot make a policy of gigabytes.
MAX_LAYER_WIDTH, MAX_LAYER_SIZES = 4096, 64


def check_network_size(policy_kwargs: Any, where: str) -> None:
    """A ValueError naming ``where`` if the layer sizes of ``policy_kwargs`` (every integer of its
    ``net_arch`` and ``features_extractor_kwargs``) exceed :data:`MAX_LAYER_WIDTH` units or
    :data:`MAX_LAYER_SIZES` layers, before any layer is built."""
    sizes: list[int] = []

    def collect(value: Any) -> None:
        if isinstance(value, bool):
            return
        if isinstance(value, int):
            sizes.append(value)
        elif isinstance(value, (list, tuple)):
            for item in value:
                collect(item)
        elif isinstance(value, dict):
            for item in value.values():
                collect(item)

    if isinstance(policy_kwargs, dict):
        collect(policy_kwargs.get("net_arch"))
        collect(policy_kwargs.get("features_extractor_kwargs"))
    if len(sizes) > MAX_LAYER_SIZES or any(size > MAX_LAYER_WIDTH for size in sizes):
        raise ValueError(
            f"{where}: policy_kwargs names layers of up to {max(sizes):,} units ({len(sizes)} sizes); at most "
            f"{MAX_LAYER_WIDTH:,} units and {MAX_LAYER_SIZES} sizes are allowed."
        )


def non_finite_weights(policy: Any) -> str | None:
    """The name of the first floating-point tensor of ``policy``'s state that holds a NaN or an
    infinity (a run that diverged), None if every weight is finite."""
    for name, tensor in policy.state_dict().items():
        if tensor.is_floating_point() and not bool(th.isfinite(tensor).all()):
            return name
    return None


def uses_action_masks(model: Any) -> bool:
    """Whether ``model`` acts on action masks (a maskable learner with ``action_masking`` on)."""
    return bool(getattr(model, "action_masking", False))


def model_policy(model: Any, deterministic: bool = False) -> Policy:
    """A policy that acts with an SB3 model: each AV's observation row is one batch entry.

    :param deterministic: argmax actions; False (default) samples from the policy, the authors'
        evaluation protocol. A maskable model with ``action_masking`` gets the env's action masks.
    """
    masked = uses_action_masks(model)
    # a centralised critic's model takes Dict observations; its actor reads only each AV's own view
    space = model.observation_space
    state_slots = int(space[STATE_KEY].shape[0]) if isinstance(space, spaces.Dict) else 0  # type: ignore[index]

    def act(env: LaneChangeEnv, obs: np.ndarray) -> np.ndarray:
        inputs = centralised_observations(obs, state_slots) if state_slots else obs
        with unchecked_distributions():
            if masked:
                return model.predict(inputs, deterministic=deterministic, action_masks=env.action_masks())[0]
            return model.predict(inputs, deterministic=deterministic)[0]

    return act
