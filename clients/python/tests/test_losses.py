"""Loss pieces against hand computation."""

from __future__ import annotations

import math

import numpy as np
import torch

from conftest import fixed_latents
from vamos.train.config import ModelConfig
from vamos.train.losses import free_bits_kl, kl_diagonal_gaussians, training_loss, weight_norm
from vamos.train.model import ProbabilisticUNet


def test_kl_matches_hand_computation() -> None:
    mu_q = torch.tensor([[0.5, -1.0]])
    ls_q = torch.tensor([[math.log(0.5), 0.0]])
    mu_p = torch.tensor([[0.0, 1.0]])
    ls_p = torch.tensor([[0.0, math.log(2.0)]])
    # dim 0: q = N(0.5, 0.5^2), p = N(0, 1): log(1/0.5) + (0.25 + 0.25)/2 - 0.5
    d0 = math.log(2.0) + (0.25 + 0.25) / 2.0 - 0.5
    # dim 1: q = N(-1, 1), p = N(1, 4): log(2/1) + (1 + 4)/(2*4) - 0.5
    d1 = math.log(2.0) + 5.0 / 8.0 - 0.5
    kl = kl_diagonal_gaussians(mu_q, ls_q, mu_p, ls_p)
    assert kl.shape == (1,)
    assert abs(float(kl[0]) - (d0 + d1)) < 1e-6


def test_kl_zero_for_equal_and_positive_otherwise() -> None:
    g = torch.Generator().manual_seed(1)
    mu, ls = torch.randn(4, 6, generator=g), torch.randn(4, 6, generator=g)
    assert torch.allclose(kl_diagonal_gaussians(mu, ls, mu, ls), torch.zeros(4), atol=1e-6)
    assert bool((kl_diagonal_gaussians(mu, ls, mu + 0.1, ls) > 0).all())


def test_kl_matches_monte_carlo() -> None:
    """Analytic KL against a Monte-Carlo estimate E_q[log q - log p] (independent formula)."""
    rng = np.random.default_rng(0)
    mu_q, s_q, mu_p, s_p = np.array([0.3, -0.2]), np.array([0.7, 1.3]), np.array([-0.1, 0.4]), np.array([1.1, 0.9])
    x = mu_q + s_q * rng.standard_normal((400_000, 2))

    def log_normal(v: np.ndarray, m: np.ndarray, s: np.ndarray) -> np.ndarray:
        return -0.5 * ((v - m) / s) ** 2 - np.log(s) - 0.5 * np.log(2 * np.pi)

    mc = float(np.mean(np.sum(log_normal(x, mu_q, s_q) - log_normal(x, mu_p, s_p), axis=1)))
    analytic = float(kl_diagonal_gaussians(
        *(torch.from_numpy(np.stack([v])) for v in (mu_q, np.log(s_q), mu_p, np.log(s_p)))
    )[0])
    assert abs(mc - analytic) < 0.01


def test_weight_norm_covers_prior_posterior_fcomb_only() -> None:
    torch.manual_seed(0)
    model = ProbabilisticUNet(ModelConfig(filters=(4, 8), latent_dim=2))
    expected = 0.0
    for part in (model.prior, model.posterior, model.fcomb):
        for p in part.parameters():
            expected += math.sqrt(float((p.detach().double() ** 2).sum()))
    assert abs(float(weight_norm(model).detach()) - expected) < 1e-4
    # U-Net weights do not enter the term.
    before = float(weight_norm(model).detach())
    with torch.no_grad():
        for p in model.unet.parameters():
            p.mul_(3.0)
    assert float(weight_norm(model).detach()) == before


def test_total_loss_combines_pieces() -> None:
    torch.manual_seed(0)
    model = ProbabilisticUNet(ModelConfig(filters=(4, 8), latent_dim=2))
    past, target = torch.rand(2, 2, 64, 64) - 0.5, torch.rand(2, 2, 64, 64) - 0.5
    eps = torch.randn(2, 2)
    torch.set_grad_enabled(False)
    terms = training_loss(model, past, target, eps, beta=10.0, weight_decay=1e-5)
    prediction, (mu_q, ls_q), (mu_p, ls_p) = model(past, target, eps)
    mse = float(((prediction - target) ** 2).double().mean())
    kl_rows = kl_diagonal_gaussians(mu_q, ls_q, mu_p, ls_p)
    assert abs(float(terms.mse) - mse) < 1e-7
    assert abs(float(terms.kl) - float(kl_rows.mean())) < 1e-6
    want = mse + 10.0 * float(kl_rows.mean()) + 1e-5 * float(weight_norm(model))
    assert abs(float(terms.total) - want) < 1e-5
    torch.set_grad_enabled(True)


def test_free_bits_floors_each_dimension_of_the_batch_mean() -> None:
    # Per-row, per-dimension KLs of a batch of two; batch means per dimension: 0.03, 0.4, 0.0.
    kl = torch.tensor([[0.02, 0.5, 0.0], [0.04, 0.3, 0.0]])
    assert abs(float(free_bits_kl(kl, 0.0)) - 0.43) < 1e-6  # off: the plain KL
    assert abs(float(free_bits_kl(kl, 0.1)) - (0.1 + 0.4 + 0.1)) < 1e-6
    assert abs(float(free_bits_kl(kl, 0.5)) - (0.5 + 0.5 + 0.5)) < 1e-6
    # The floor applies to the batch mean, not to each row: 0.35 > 0.3 for row 2 alone.
    assert abs(float(free_bits_kl(kl, 0.35)) - (0.35 + 0.4 + 0.35)) < 1e-6


def _v(t: torch.Tensor) -> float:
    return float(t.detach())


def test_free_bits_in_the_training_loss_hand_computed() -> None:
    torch.manual_seed(0)
    model = ProbabilisticUNet(ModelConfig(filters=(4, 8), latent_dim=3, input_size=16))
    # KL per dimension of N(mu, 1) || N(0, 1) is mu^2 / 2: 0.005, 0.5, 0.
    fixed_latents(model, [0.1, 1.0, 0.0])
    past, target = torch.rand(2, 2, 16, 16) - 0.5, torch.rand(2, 2, 16, 16) - 0.5
    eps = torch.randn(2, 3)
    plain = training_loss(model, past, target, eps, beta=10.0, weight_decay=1e-5)
    floored = training_loss(model, past, target, eps, beta=10.0, weight_decay=1e-5, free_bits=0.1)
    reg = float(weight_norm(model).detach())
    for terms in (plain, floored):
        assert abs(_v(terms.kl) - 0.505) < 1e-6  # the true KL, whatever free_bits is
    assert abs(_v(plain.kl_term) - 0.505) < 1e-6
    assert abs(_v(floored.kl_term) - (0.1 + 0.5 + 0.1)) < 1e-6
    assert _v(floored.mse) == _v(plain.mse)
    assert abs(_v(floored.total) - (_v(floored.mse) + 10.0 * 0.7 + 1e-5 * reg)) < 1e-5
    assert abs(_v(plain.total) - (_v(plain.mse) + 10.0 * 0.505 + 1e-5 * reg)) < 1e-5
    # Below the floor a dimension's KL has no gradient; above it, d(mu^2 / 2)/d mu = mu.
    grad = torch.autograd.grad(floored.kl_term, model.posterior.to_params.bias)[0]
    assert torch.allclose(grad[:3], torch.tensor([0.0, 1.0, 0.0]), atol=1e-6)
    grad = torch.autograd.grad(plain.kl_term, model.posterior.to_params.bias)[0]
    assert torch.allclose(grad[:3], torch.tensor([0.1, 1.0, 0.0]), atol=1e-6)
