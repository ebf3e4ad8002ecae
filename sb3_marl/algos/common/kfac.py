"""K-FAC (Martens and Grosse 2015; Grosse and Martens 2016 for convolutions): natural-gradient
steps under a Kronecker-factored Fisher, scaled down to a trust region on the KL divergence between
successive policies; the optimiser of :class:`~sb3_marl.algos.acktr.ACKTR` (choices there)."""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import contextmanager
from functools import partial
from typing import Any

import torch as th
import torch.nn.functional as F
from torch import nn

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
