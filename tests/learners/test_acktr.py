"""ACKTR and its K-FAC optimiser: factors, natural-gradient step, trust region, learning, save/load."""

import gymnasium as gym
import numpy as np
import pytest
import torch as th
import torch.nn.functional as F
from documents import code
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.evaluation import evaluate_policy
from torch import nn

from sb3_marl.algos import get_algo
from sb3_marl.algos.acktr import ACKTR, KFAC, MaskableACKTR


def fisher_targets(logits: th.Tensor, seed: int) -> th.Tensor:
    """Targets sampled from the model's own categorical distribution (the Fisher's)."""
    generator = th.Generator().manual_seed(seed)
    return th.multinomial(F.softmax(logits.detach(), dim=1), 1, generator=generator).flatten()


class TinyNet(nn.Module):
    """conv 2x2 (1 -> 2 channels, 3x3 input) -> tanh -> linear 8 -> 3 -> tanh -> linear 3 -> 4."""

    def __init__(self) -> None:
        super().__init__()
        self.conv = nn.Conv2d(1, 2, kernel_size=2)
        self.hidden = nn.Linear(8, 3)
        self.out = nn.Linear(3, 4)

    def forward(self, x: th.Tensor, keep: dict | None = None) -> th.Tensor:
        z_conv = self.conv(x)
        h1 = th.tanh(z_conv).flatten(1)
        z_hidden = self.hidden(h1)
        h2 = th.tanh(z_hidden)
        z_out = self.out(h2)
        if keep is not None:
            keep.update(conv=(x, z_conv), hidden=(h1, z_hidden), out=(h2, z_out))
            for _, z in keep.values():
                z.retain_grad()
        return z_out


def test_kfac_factors_match_explicit_loops():
    th.manual_seed(0)
    net = TinyNet().double()
    optimizer = KFAC(net)
    x = th.randn(5, 1, 3, 3, dtype=th.float64)
    with optimizer.record_statistics():
        logits = net(x)
        targets = fisher_targets(logits, seed=1)
        F.cross_entropy(logits, targets).backward()  # mean over the batch of -log p(target)

    batch = x.shape[0]
    expected = {name: {"A": 0, "G": 0} for name in ("conv", "hidden", "out")}
    for i in range(batch):  # one sample at a time: its own input vectors and output gradients
        keep: dict = {}
        logits_i = net(x[i : i + 1], keep)
        F.cross_entropy(logits_i, targets[i : i + 1]).backward()
        for name in ("hidden", "out"):
            a, z = keep[name]
            a_bar = th.cat([a[0], th.ones(1, dtype=a.dtype)])
            expected[name]["A"] = expected[name]["A"] + th.outer(a_bar, a_bar) / batch
            expected[name]["G"] = expected[name]["G"] + th.outer(z.grad[0], z.grad[0]) / batch
        image, z = keep["conv"]
        positions = [(r, c) for r in range(2) for c in range(2)]  # output positions of a 2x2 kernel on 3x3
        for r, c in positions:
            patch = image[0, :, r : r + 2, c : c + 2].reshape(-1)  # (channel, row, column) order
            a_bar = th.cat([patch, th.ones(1, dtype=patch.dtype)]) / len(positions)
            expected["conv"]["A"] = expected["conv"]["A"] + th.outer(a_bar, a_bar) / batch
            g = z.grad[0, :, r, c] * len(positions)
            expected["conv"]["G"] = expected["conv"]["G"] + th.outer(g, g) / (batch * len(positions))
    for name, layer in (("conv", net.conv), ("hidden", net.hidden), ("out", net.out)):
        for factor in ("A", "G"):
            th.testing.assert_close(optimizer.state[layer.weight][factor], expected[name][factor], msg=f"{name} {factor}")


def test_running_averages_decay():
    net = nn.Linear(2, 2).double()
    optimizer = KFAC(net, stat_decay=0.9)
    inputs = [th.tensor([[1.0, 0.0]], dtype=th.float64), th.tensor([[0.0, 2.0]], dtype=th.float64)]
    for x in inputs:
        with optimizer.record_statistics():
            net(x).sum().backward()
    a1, a2 = (th.outer(th.cat([x[0], th.ones(1, dtype=x.dtype)]), th.cat([x[0], th.ones(1, dtype=x.dtype)])) for x in inputs)
    th.testing.assert_close(optimizer.state[net.weight]["A"], 0.9 * a1 + 0.1 * a2)
    with th.no_grad():  # outside the block, or without gradients: nothing recorded
        net(inputs[0])
    net(inputs[0]).sum().backward()
    th.testing.assert_close(optimizer.state[net.weight]["A"], 0.9 * a1 + 0.1 * a2)


class TwoHeads(nn.Module):
    """Two independent linear heads; each sample's Fisher loss uses one head only."""

    def __init__(self) -> None:
        super().__init__()
        self.first = nn.Linear(3, 2)
        self.second = nn.Linear(2, 3)

    def forward(self, x1: th.Tensor, x2: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        return self.first(x1), self.second(x2)


def per_sample_losses(model: TwoHeads, x1, x2, targets) -> list[th.Tensor]:
    logits1, logits2 = model(x1, x2)
    return [F.cross_entropy((logits1 if i % 2 == 0 else logits2)[i : i + 1], targets[i : i + 1]) for i in range(len(targets))]


def test_kfac_step_is_the_exact_natural_gradient_step_when_the_fisher_factorises():
    """Constant inputs per layer and one head per sample make the exact Fisher block-diagonal and
    each block exactly G ⊗ A; the K-FAC step must then be (F + damping I)^-1 times the gradient."""
    th.manual_seed(0)
    model = TwoHeads().double()
    damping = 1e-2
    optimizer = KFAC(model, lr=1.0, momentum=0.0, damping=damping, kl_clip=1e9)
    batch = 8
    x1 = th.randn(1, 3, dtype=th.float64).repeat(batch, 1)
    x2 = th.randn(1, 2, dtype=th.float64).repeat(batch, 1)
    with th.no_grad():
        logits1, logits2 = model(x1, x2)
    targets = th.cat([fisher_targets(logits1, 2), fisher_targets(logits2, 3)]).reshape(2, batch).T
    targets = th.where(th.arange(batch) % 2 == 0, targets[:, 0], targets[:, 1])
    with optimizer.record_statistics():
        th.stack(per_sample_losses(model, x1, x2, targets)).mean().backward()

    params = [model.first.weight, model.first.bias, model.second.weight, model.second.bias]

    def flat(w1, b1, w2, b2) -> th.Tensor:  # row-major [weight | bias] of each layer
        return th.cat([th.cat([w1, b1[:, None]], 1).flatten(), th.cat([w2, b2[:, None]], 1).flatten()])

    def flat_grad(loss: th.Tensor) -> th.Tensor:
        return flat(*th.autograd.grad(loss, params, allow_unused=True, materialize_grads=True, retain_graph=True))

    jacobian = th.stack([flat_grad(loss) for loss in per_sample_losses(model, x1, x2, targets)])
    fisher = jacobian.T @ jacobian / batch
    assert th.count_nonzero(fisher[:8, 8:]) == 0  # block-diagonal by construction

    optimizer.zero_grad()
    logits1, logits2 = model(x1 * 0.5, x2 * 2.0)
    objective = (logits1 * th.tensor([0.3, -1.0])).sum() + (logits2**2).sum()
    objective.backward()
    gradient = flat(*(p.grad for p in params))
    before = [p.detach().clone() for p in params]
    optimizer.step()
    step = flat(*(p.detach() - p0 for p, p0 in zip(params, before)))
    exact = -th.linalg.solve(fisher + damping * th.eye(len(gradient), dtype=th.float64), gradient)
    th.testing.assert_close(step, exact, rtol=1e-7, atol=1e-9)
    assert optimizer.last_step_scale == 1.0


@pytest.mark.parametrize("lr, clipped", [(1e-4, False), (10.0, True)])
def test_kl_clip_bounds_the_step(lr, clipped):
    th.manual_seed(0)
    net = nn.Sequential(nn.Linear(4, 5), nn.Tanh(), nn.Linear(5, 3)).double()
    kl_clip, damping = 1e-3, 1e-2
    optimizer = KFAC(net, lr=lr, momentum=0.0, kl_clip=kl_clip, damping=damping)
    x = th.randn(16, 4, dtype=th.float64)
    with optimizer.record_statistics():
        logits = net(x)
        F.cross_entropy(logits, fisher_targets(logits, 0)).backward()
    optimizer.zero_grad()
    F.cross_entropy(net(x), th.arange(16) % 3).backward()
    layers = [net[0], net[2]]
    before = [(layer.weight.detach().clone(), layer.bias.detach().clone()) for layer in layers]
    gradients = [th.cat([layer.weight.grad, layer.bias.grad[:, None]], 1) for layer in layers]
    optimizer.step()
    quadratic = 0.0  # step' (G ⊗ A + damping I) step, the trust region's KL estimate
    for layer, (w0, b0), gradient in zip(layers, before, gradients):
        step = th.cat([layer.weight - w0, (layer.bias - b0)[:, None]], 1).detach()
        state = optimizer.state[layer.weight]
        a = state["Q_A"] @ th.diag(state["d_A"]) @ state["Q_A"].T
        g = state["Q_G"] @ th.diag(state["d_G"]) @ state["Q_G"].T
        quadratic += float((step * (g @ step @ a + damping * step)).sum())
        if not clipped:  # inside the trust region the step is the full natural-gradient step
            eye = th.eye(g.shape[0] * a.shape[0], dtype=a.dtype)
            natural = th.linalg.solve(th.kron(g, a) + damping * eye, gradient.flatten())  # row-major vec
            th.testing.assert_close(step.flatten(), -lr * natural, rtol=1e-6, atol=1e-12)
    if clipped:
        assert optimizer.last_step_scale < 1.0
        assert quadratic == pytest.approx(kl_clip, rel=1e-6)
    else:
        assert optimizer.last_step_scale == 1.0
        assert quadratic < kl_clip


def test_kfac_needs_statistics_and_valid_settings():
    net = nn.Linear(2, 2)
    optimizer = KFAC(net)
    net(th.ones(1, 2)).sum().backward()
    with pytest.raises(RuntimeError, match="no curvature statistics"):
        optimizer.step()
    for kwargs, match in (
        ({"kl_clip": 0.0}, "kl_clip=0.0"),
        ({"momentum": 1.0}, "momentum=1.0"),
        ({"inverse_update_freq": 0}, "inverse_update_freq=0"),
    ):
        with pytest.raises(ValueError, match=match):
            KFAC(net, **kwargs)


def test_the_docs_example_solves_cartpole():
    """The Learners page's ACKTR example, run verbatim (about 20 s on 2 cores), then evaluated."""
    namespace: dict = {}
    exec(compile(code("learners.md", "ACKTR"), "learners.md", "exec"), namespace)
    model = namespace["model"]
    eval_env = gym.make("CartPole-v1")
    eval_env.reset(seed=100)
    returns, _ = evaluate_policy(model, eval_env, n_eval_episodes=10, deterministic=True, return_episode_rewards=True)
    assert np.mean(returns) >= 475, returns


def test_save_load_round_trip(tmp_path):
    env = make_vec_env("CartPole-v1", n_envs=4, seed=0)
    model = ACKTR("MlpPolicy", env, n_steps=8, seed=0, device="cpu")
    model.learn(640)
    model.save(tmp_path / "acktr.zip")
    loaded = ACKTR.load(tmp_path / "acktr.zip", env=env, device="cpu")
    assert isinstance(loaded.policy.optimizer, KFAC) and loaded.kl_clip == model.kl_clip
    for layer, loaded_layer in zip(model.policy.optimizer.layers, loaded.policy.optimizer.layers):
        for key in ("A", "G", "Q_A", "momentum_buffer"):
            saved, restored = model.policy.optimizer.state[layer.weight], loaded.policy.optimizer.state[loaded_layer.weight]
            th.testing.assert_close(saved[key], restored[key])
    assert loaded.policy.optimizer.group["steps"] == model.policy.optimizer.group["steps"] == 20
    obs = env.reset()
    np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0], loaded.predict(obs, deterministic=True)[0])
    statistics = loaded.policy.optimizer.state[loaded.policy.optimizer.layers[0].weight]["A"].clone()
    loaded.learn(64, reset_num_timesteps=False)  # the loaded optimiser records statistics and steps again
    assert not th.equal(statistics, loaded.policy.optimizer.state[loaded.policy.optimizer.layers[0].weight]["A"])


def test_box_actions_train_the_log_std():
    env = make_vec_env("Pendulum-v1", n_envs=2, seed=0)
    model = ACKTR("MlpPolicy", env, n_steps=8, seed=0, device="cpu")
    log_std = model.policy.log_std.detach().clone()
    model.learn(160)
    assert not th.equal(log_std, model.policy.log_std.detach())


def test_registered_as_maacktr_and_acktr():
    assert get_algo("maacktr") is MaskableACKTR and get_algo("acktr") is MaskableACKTR
    assert issubclass(MaskableACKTR, ACKTR)
