"""ACKTR: actor-critic using a Kronecker-factored trust region, as a Stable-Baselines3 algorithm.

Wu, Mansimov, Liao, Grosse and Ba (2017), "Scalable trust-region method for deep reinforcement
learning using Kronecker-factored approximation". ACKTR is A2C (synchronous n-step rollouts, one
update per rollout) whose optimiser is K-FAC (Martens and Grosse 2015; Grosse and Martens 2016
for convolutions): natural-gradient steps under a Kronecker-factored Fisher, scaled down to a
trust region on the KL divergence between successive policies.

Read top to bottom: :class:`KFAC` (curvature statistics, preconditioning, trust region, update),
then :class:`ACKTR` (the SB3 algorithm; rollouts as A2C, ``train`` feeds K-FAC its statistics).

Choices, after OpenAI baselines' ``acktr`` and ikostrikov's pytorch-a2c-ppo-acktr-gail:

- learning rate 0.25, momentum 0.9, KL clip 0.001, damping 0.01 (baselines' and ikostrikov's);
- running averages of the factors with decay 0.99, updated on every update (``stats_update_freq``
  1, ikostrikov's ``Ts``); eigen-decompositions every 10 updates (``inverse_update_freq``,
  ikostrikov's ``Tf``), synchronously (baselines runs them asynchronously on a queue);
- the Fisher of the policy from actions sampled from the policy itself: the rollout's actions, as
  one update per rollout means they were drawn from the current parameters; the Fisher of the
  critic from a Gaussian value head with unit variance (targets ``value + N(0, 1)``);
- no gradient-norm clipping: the KL clip bounds the step.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import contextmanager, nullcontext
from functools import partial
from typing import Any, ClassVar, TypeVar

import numpy as np
import torch as th
import torch.nn.functional as F
from gymnasium import spaces
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
from stable_baselines3.common.policies import (
    ActorCriticCnnPolicy,
    ActorCriticPolicy,
    BasePolicy,
    MultiInputActorCriticPolicy,
)
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule
from stable_baselines3.common.utils import explained_variance
from torch import nn

SelfACKTR = TypeVar("SelfACKTR", bound="ACKTR")

#: Layer types whose [weight | bias] gets a Kronecker-factored Fisher block.
KFAC_LAYERS = (nn.Linear, nn.Conv2d)


class KFAC(th.optim.Optimizer):
    """K-FAC natural-gradient optimiser with ACKTR's KL trust region.

    For each ``nn.Linear`` / ``nn.Conv2d`` layer, the Fisher block of its parameters, laid out as
    the matrix ``[weight | bias]`` of shape (out, in + 1), is approximated by ``G ⊗ A``:
    ``A = E[ā āᵀ]`` over the layer inputs ā with a 1 appended for the bias (for a convolution:
    over input patches, as ``F.unfold`` lays them out), ``G = E[g gᵀ]`` over the per-sample
    gradients g of a Fisher loss w.r.t. the layer outputs. Both are running averages
    (``stat_decay``) of batch estimates, recorded only inside :meth:`record_statistics`. Every
    ``inverse_update_freq`` steps ``A = Q_A diag(d_A) Q_Aᵀ`` and ``G = Q_G diag(d_G) Q_Gᵀ`` are
    recomputed, and the gradient ∇ of a layer is preconditioned as
    ``v = Q_G [(Q_Gᵀ ∇ Q_A) / (d_G d_Aᵀ + damping)] Q_Aᵀ = (G ⊗ A + damping·I)⁻¹ ∇``.
    Other parameters (e.g. a Gaussian policy's log std) keep their plain gradient.

    Trust region: with ``lr²·Σ v·∇`` the quadratic estimate of the KL divergence of the step
    ``lr·v``, the step is scaled by ``ν = min(1, sqrt(kl_clip / (lr²·Σ v·∇)))``. Update: SGD with
    momentum on ``ν·v`` at learning rate ``lr·(1 − momentum)``, so that the steady-state step is
    ``lr·ν·v`` (ikostrikov's choice).

    :param model: the module to optimise; hooks are registered on its Linear and Conv2d layers
    :param lr: learning rate (SB3 updates ``param_groups[0]["lr"]`` from its schedule)
    :param momentum: SGD momentum
    :param stat_decay: decay of the running averages of A and G
    :param damping: Tikhonov damping added to the Kronecker-factored Fisher
    :param kl_clip: bound on the quadratic KL estimate of one step
    :param inverse_update_freq: steps between eigen-decompositions of the factors
    """

    def __init__(
        self,
        model: nn.Module,
        lr: float = 0.25,
        momentum: float = 0.9,
        stat_decay: float = 0.99,
        damping: float = 1e-2,
        kl_clip: float = 1e-3,
        inverse_update_freq: int = 10,
    ) -> None:
        for name, value, low in (("lr", lr, 0.0), ("damping", damping, 0.0), ("kl_clip", kl_clip, 0.0)):
            if not value > low:
                raise ValueError(f"Invalid {name}={value!r}: expected a number > {low}.")
        if not 0.0 <= momentum < 1.0 or not 0.0 <= stat_decay < 1.0:
            raise ValueError(f"Invalid momentum={momentum!r} or stat_decay={stat_decay!r}: expected numbers in [0, 1).")
        if not isinstance(inverse_update_freq, int) or inverse_update_freq < 1:
            raise ValueError(f"Invalid inverse_update_freq={inverse_update_freq!r}: expected an integer >= 1.")
        defaults = dict(
            lr=lr,
            momentum=momentum,
            stat_decay=stat_decay,
            damping=damping,
            kl_clip=kl_clip,
            inverse_update_freq=inverse_update_freq,
            steps=0,
        )
        super().__init__(model.parameters(), defaults)
        self.layers = [module for module in model.modules() if isinstance(module, KFAC_LAYERS)]
        for layer in self.layers:
            if isinstance(layer, nn.Conv2d) and (
                layer.groups != 1 or layer.dilation != (1, 1) or layer.padding_mode != "zeros"
            ):
                raise ValueError(f"KFAC supports Conv2d with groups=1, dilation=1, zero padding only, got {layer}.")
            layer.register_forward_hook(self._record_inputs)
        self._recording = False
        #: ν of the last step (1: the natural-gradient step was inside the trust region)
        self.last_step_scale = 1.0

    # --- curvature statistics ---------------------------------------------------------------

    @contextmanager
    def record_statistics(self) -> Iterator[None]:
        """Inside the block, forward passes (with gradients) record the layer inputs and backward
        passes the output gradients, into the running averages A and G. Run one forward pass on a
        batch and one backward pass of a Fisher loss (the mean over the batch of the log-likelihood
        of targets sampled from the model) in it."""
        self._recording = True
        try:
            yield
        finally:
            self._recording = False

    def _record_inputs(self, layer: nn.Module, inputs: tuple[th.Tensor, ...], output: th.Tensor) -> None:
        """Forward hook: A's batch estimate, and a hook on the output for G's."""
        if not (self._recording and th.is_grad_enabled()):
            return
        output.register_hook(partial(self._record_output_gradients, layer))
        with th.no_grad():
            a, spatial = inputs[0], 1
            if isinstance(layer, nn.Conv2d):  # (batch, C, H, W) -> patches (batch * L, C * kh * kw)
                batch = a.shape[0]
                patches = F.unfold(a, layer.kernel_size, padding=layer.padding, stride=layer.stride)  # type: ignore[arg-type]
                spatial = patches.shape[2]
                a = patches.transpose(1, 2).reshape(-1, patches.shape[1])
            else:
                a = a.reshape(-1, a.shape[-1])
                batch = a.shape[0]
            if layer.bias is not None:
                a = th.cat([a, a.new_ones(a.shape[0], 1)], dim=1)
            a = a / spatial  # convolutions: Grosse and Martens (2016)'s scaling, as ikostrikov's
            self._update_average(layer.weight, "A", a.T @ a / batch)  # type: ignore[arg-type]

    def _record_output_gradients(self, layer: nn.Module, g: th.Tensor) -> None:
        """Hook on a layer output's gradient: G's batch estimate (only inside record_statistics)."""
        if not self._recording:
            return
        with th.no_grad():
            if isinstance(layer, nn.Conv2d):  # (batch, out, H, W) -> (batch * H * W, out)
                g = g.permute(0, 2, 3, 1).reshape(-1, g.shape[1])
            else:
                g = g.reshape(-1, g.shape[-1])
            g = g * g.shape[0]  # gradients of a mean over the rows -> per-row gradients
            self._update_average(layer.weight, "G", g.T @ g / g.shape[0])  # type: ignore[arg-type]

    def _update_average(self, weight: th.Tensor, name: str, estimate: th.Tensor) -> None:
        """Running average with decay ``stat_decay``, started at the first estimate."""
        state, decay = self.state[weight], self.group["stat_decay"]
        if name in state:
            state[name].mul_(decay).add_(estimate, alpha=1 - decay)
        else:
            state[name] = estimate.clone()

    @property
    def group(self) -> dict[str, Any]:
        """The single parameter group: the current lr and the K-FAC settings."""
        return self.param_groups[0]

    # --- preconditioning, trust region, update -----------------------------------------------

    def natural_gradients(self) -> dict[th.Tensor, th.Tensor]:
        """Preconditioned gradient v of every parameter that has a gradient (see the class doc)."""
        group = self.group
        updates: dict[th.Tensor, th.Tensor] = {}
        for layer in self.layers:
            weight, bias = layer.weight, layer.bias
            if weight.grad is None:
                continue
            state = self.state[weight]
            if "A" not in state or "G" not in state:
                raise RuntimeError(
                    f"KFAC has no curvature statistics for {layer}: run a forward pass and the backward "
                    "pass of a Fisher loss inside optimizer.record_statistics() before the first step."
                )
            if "Q_A" not in state or group["steps"] % group["inverse_update_freq"] == 0:
                for factor in ("A", "G"):
                    eigenvalues, eigenvectors = th.linalg.eigh(state[factor])
                    state[f"d_{factor}"] = eigenvalues * (eigenvalues > 1e-6)  # drop round-off negatives
                    state[f"Q_{factor}"] = eigenvectors
            gradient = weight.grad.reshape(weight.shape[0], -1)
            if bias is not None:
                gradient = th.cat([gradient, bias.grad[:, None]], dim=1)  # type: ignore[index]
            q_a, q_g = state["Q_A"], state["Q_G"]
            scaled = (q_g.T @ gradient @ q_a) / (state["d_G"][:, None] * state["d_A"][None, :] + group["damping"])
            v = q_g @ scaled @ q_a.T
            if bias is not None:
                updates[bias] = v[:, -1].contiguous()
                v = v[:, :-1]
            updates[weight] = v.reshape(weight.shape)
        for parameter in group["params"]:
            if parameter.grad is not None and parameter not in updates:
                updates[parameter] = parameter.grad.clone()
        return updates

    @th.no_grad()
    def step(self, closure: Any = None) -> None:  # type: ignore[override]
        """One trust-region natural-gradient step on the current gradients."""
        if closure is not None:
            raise ValueError("KFAC.step takes no closure: compute the gradients first.")
        group = self.group
        updates = self.natural_gradients()
        lr = group["lr"]
        kl_estimate = float(sum((v * p.grad).sum() for p, v in updates.items())) * lr**2  # type: ignore[misc, operator]
        self.last_step_scale = min(1.0, math.sqrt(group["kl_clip"] / kl_estimate)) if kl_estimate > 0 else 1.0
        for parameter, v in updates.items():
            state = self.state[parameter]
            v = v * self.last_step_scale
            if "momentum_buffer" in state:
                v = state["momentum_buffer"].mul_(group["momentum"]).add_(v)
            else:
                state["momentum_buffer"] = v.clone()
            parameter.add_(v, alpha=-lr * (1 - group["momentum"]))
        group["steps"] += 1


class ACKTR(OnPolicyAlgorithm):
    """ACKTR: A2C-style actor-critic trained with :class:`KFAC` (see the module doc).

    Same policies as SB3's A2C (``MlpPolicy``, ``CnnPolicy``, ``MultiInputPolicy``, and the MA2C
    feature extractor through ``policy_kwargs``); Discrete, MultiDiscrete, MultiBinary and Box
    action spaces; saved and loaded in SB3's format (K-FAC's statistics included).

    :param learning_rate: K-FAC learning rate, or a schedule of the remaining progress
    :param n_steps: steps per env per update (rollout length)
    :param gamma: discount factor
    :param gae_lambda: GAE lambda; 1.0 gives plain n-step returns, as in the paper
    :param ent_coef: entropy coefficient
    :param vf_coef: value loss coefficient
    :param momentum: K-FAC SGD momentum
    :param stat_decay: decay of K-FAC's running curvature averages
    :param damping: K-FAC damping
    :param kl_clip: trust-region bound on the KL estimate of one update
    :param inverse_update_freq: updates between eigen-decompositions of the factors
    :param stats_update_freq: updates between curvature-statistics recordings
    :param vf_fisher_coef: weight of the critic's Gaussian Fisher loss beside the policy's
    :param normalize_advantage: whether to normalise the advantages of each rollout
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {
        "MlpPolicy": ActorCriticPolicy,
        "CnnPolicy": ActorCriticCnnPolicy,
        "MultiInputPolicy": MultiInputActorCriticPolicy,
    }

    def __init__(
        self,
        policy: str | type[ActorCriticPolicy],
        env: GymEnv | str,
        learning_rate: float | Schedule = 0.25,
        n_steps: int = 20,
        gamma: float = 0.99,
        gae_lambda: float = 1.0,
        ent_coef: float = 0.01,
        vf_coef: float = 0.5,
        momentum: float = 0.9,
        stat_decay: float = 0.99,
        damping: float = 1e-2,
        kl_clip: float = 1e-3,
        inverse_update_freq: int = 10,
        stats_update_freq: int = 1,
        vf_fisher_coef: float = 1.0,
        normalize_advantage: bool = False,
        use_sde: bool = False,
        sde_sample_freq: int = -1,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        _init_setup_model: bool = True,
    ) -> None:
        super().__init__(
            policy,
            env,
            learning_rate=learning_rate,
            n_steps=n_steps,
            gamma=gamma,
            gae_lambda=gae_lambda,
            ent_coef=ent_coef,
            vf_coef=vf_coef,
            max_grad_norm=math.inf,  # unused: the KL clip bounds the step
            use_sde=use_sde,
            sde_sample_freq=sde_sample_freq,
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            policy_kwargs=policy_kwargs,
            verbose=verbose,
            seed=seed,
            device=device,
            _init_setup_model=False,
            supported_action_spaces=(spaces.Box, spaces.Discrete, spaces.MultiDiscrete, spaces.MultiBinary),
        )
        if not isinstance(stats_update_freq, int) or stats_update_freq < 1:
            raise ValueError(f"Invalid stats_update_freq={stats_update_freq!r}: expected an integer >= 1.")
        self.momentum = momentum
        self.stat_decay = stat_decay
        self.damping = damping
        self.kl_clip = kl_clip
        self.inverse_update_freq = inverse_update_freq
        self.stats_update_freq = stats_update_freq
        self.vf_fisher_coef = vf_fisher_coef
        self.normalize_advantage = normalize_advantage
        if _init_setup_model:
            self._setup_model()

    def _setup_model(self) -> None:
        super()._setup_model()
        self._setup_optimizer()

    def _setup_optimizer(self) -> None:
        """Replace the policy's optimiser with :class:`KFAC` (hooks on its layers)."""
        self.policy.optimizer = KFAC(
            self.policy,
            lr=self.lr_schedule(1),
            momentum=self.momentum,
            stat_decay=self.stat_decay,
            damping=self.damping,
            kl_clip=self.kl_clip,
            inverse_update_freq=self.inverse_update_freq,
        )

    def train(self) -> None:
        """One K-FAC update on the rollout buffer (one batch)."""
        self.policy.set_training_mode(True)
        optimizer: KFAC = self.policy.optimizer  # type: ignore[assignment]
        self._update_learning_rate(optimizer)
        buffer = self.rollout_buffer
        indices = np.random.permutation(buffer.buffer_size * buffer.n_envs)  # as the buffer's get() draws it
        if not buffer.generator_ready:
            state = np.random.get_state()
            next(buffer.get(batch_size=None))  # flattens the arrays slot-major on first use
            np.random.set_state(state)
        rollout = buffer._get_samples(indices)
        actions = rollout.actions
        if isinstance(self.action_space, spaces.Discrete):
            actions = actions.long().flatten()

        record = self._n_updates % self.stats_update_freq == 0
        with optimizer.record_statistics() if record else nullcontext():
            masks = getattr(rollout, "action_masks", None)  # a maskable rollout buffer's (MaskableACKTR)
            mask_kwargs = {} if masks is None else {"action_masks": masks}
            values, log_prob, entropy = self.policy.evaluate_actions(rollout.observations, actions, **mask_kwargs)
            values = values.flatten()
            if record:  # Fisher loss: log-likelihood of model samples (see the module doc)
                optimizer.zero_grad()
                value_samples = values.detach() + th.randn_like(values)
                fisher_loss = -log_prob.mean() - self.vf_fisher_coef * (values - value_samples).pow(2).mean()
                fisher_loss.backward(retain_graph=True)

        advantages = rollout.advantages
        if self.normalize_advantage:
            advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
        policy_loss = -(advantages * log_prob).mean()
        value_loss = F.mse_loss(rollout.returns, values)
        entropy_loss = -th.mean(-log_prob) if entropy is None else -th.mean(entropy)
        loss = policy_loss + self.ent_coef * entropy_loss + self.vf_coef * value_loss
        loss = loss + self.auxiliary_loss(rollout, indices)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()

        self._n_updates += 1
        explained_var = explained_variance(self.rollout_buffer.values.flatten(), self.rollout_buffer.returns.flatten())
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        self.logger.record("train/explained_variance", explained_var)
        self.logger.record("train/entropy_loss", entropy_loss.item())
        self.logger.record("train/policy_loss", policy_loss.item())
        self.logger.record("train/value_loss", value_loss.item())
        self.logger.record("train/kl_step_scale", optimizer.last_step_scale)
        if hasattr(self.policy, "log_std"):
            self.logger.record("train/std", th.exp(self.policy.log_std).mean().item())

    def auxiliary_loss(self, rollout: Any, indices: np.ndarray) -> th.Tensor | float:
        """A term added to the update's loss on ``rollout`` (the buffer's samples at ``indices``):
        none here; subclasses add theirs in the same K-FAC step."""
        return 0.0

    def learn(
        self: SelfACKTR,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 100,
        tb_log_name: str = "ACKTR",
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfACKTR:
        return super().learn(
            total_timesteps=total_timesteps,
            callback=callback,
            log_interval=log_interval,
            tb_log_name=tb_log_name,
            reset_num_timesteps=reset_num_timesteps,
            progress_bar=progress_bar,
        )
