"""The training loss: ``mse + beta * kl + weight_decay * weight_norm``.

Exactly:

- ``mse``: mean over every element (batch, channel, pixel) of ``(prediction - target)^2``.
- ``kl``: analytic KL(posterior || prior) of the diagonal Gaussians, summed over the latent
  dimensions, averaged over the batch.
- ``weight_norm``: for every parameter tensor (weights and biases) of the prior net, the
  posterior net and fcomb, its (unsquared) Frobenius norm ``sqrt(sum(w^2))``, summed over
  tensors. The U-Net is not regularised. Coefficient ``weight_decay`` = 1e-5 (reference code).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from vamos.train.model import ProbabilisticUNet


def kl_diagonal_gaussians(mu_q: Tensor, log_sigma_q: Tensor, mu_p: Tensor, log_sigma_p: Tensor) -> Tensor:
    """KL(q || p) per row for diagonal Gaussians given as ``[N, L]`` mean and log std; shape ``[N]``.

    ``sum_l log(s_p/s_q) + (s_q^2 + (mu_q - mu_p)^2) / (2 s_p^2) - 1/2``.
    """
    var_q = torch.exp(2.0 * log_sigma_q)
    var_p = torch.exp(2.0 * log_sigma_p)
    terms = log_sigma_p - log_sigma_q + (var_q + (mu_q - mu_p) ** 2) / (2.0 * var_p) - 0.5
    return terms.sum(dim=1)


def weight_norm(model: ProbabilisticUNet) -> Tensor:
    """Sum of the Frobenius norms of all prior, posterior and fcomb parameter tensors."""
    norms = [
        torch.linalg.vector_norm(p)
        for part in (model.prior, model.posterior, model.fcomb)
        for p in part.parameters()
    ]
    return torch.stack(norms).sum()


@dataclass
class LossTerms:
    """The loss and its pieces (tensors, for backward and logging)."""

    total: Tensor
    mse: Tensor
    kl: Tensor
    reg: Tensor


def training_loss(
    model: ProbabilisticUNet,
    past: Tensor,
    target: Tensor,
    eps: Tensor,
    beta: float,
    weight_decay: float,
) -> LossTerms:
    """Forward pass and loss of one batch (see the module doc for the exact definition)."""
    prediction, (mu_q, ls_q), (mu_p, ls_p) = model(past, target, eps)
    mse = torch.mean((prediction - target) ** 2)
    kl = kl_diagonal_gaussians(mu_q, ls_q, mu_p, ls_p).mean()
    reg = weight_norm(model)
    return LossTerms(total=mse + beta * kl + weight_decay * reg, mse=mse, kl=kl, reg=reg)
