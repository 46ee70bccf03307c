"""The training loss: ``mse + beta * kl_term + weight_decay * weight_norm``.

Exactly:

- ``mse``: mean over every element (batch, channel, pixel) of ``(prediction - target)^2``.
- ``kl``: analytic KL(posterior || prior) of the diagonal Gaussians, summed over the latent
  dimensions, averaged over the batch. This is what the logs report.
- ``kl_term``: the KL the loss uses. Without free bits (``free_bits = 0``, the default) it
  is ``kl``. With free bits (Kingma et al. 2016, "Improved variational inference with
  inverse autoregressive flow") it is ``sum_l max(kl_l, free_bits)``, where
  ``kl_l`` is latent dimension ``l``'s KL averaged over the batch: a dimension whose KL is
  below ``free_bits`` nats adds a constant (no gradient), so the optimiser gains nothing by
  pushing it further down (the remedy for posterior collapse). ``kl_term >= kl`` always.
- ``weight_norm``: for every parameter tensor (weights and biases) of the prior net, the
  posterior net and fcomb, its (unsquared) Frobenius norm ``sqrt(sum(w^2))``, summed over
  tensors. The U-Net is not regularised. Coefficient ``weight_decay`` = 1e-5 (reference code).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from vamos.train.model import ProbabilisticUNet


def kl_per_dimension(mu_q: Tensor, log_sigma_q: Tensor, mu_p: Tensor, log_sigma_p: Tensor) -> Tensor:
    """KL(q || p) per row and latent dimension for diagonal Gaussians given as ``[N, L]`` mean
    and log std; shape ``[N, L]``: ``log(s_p/s_q) + (s_q^2 + (mu_q - mu_p)^2) / (2 s_p^2) - 1/2``."""
    var_q = torch.exp(2.0 * log_sigma_q)
    var_p = torch.exp(2.0 * log_sigma_p)
    terms: Tensor = log_sigma_p - log_sigma_q + (var_q + (mu_q - mu_p) ** 2) / (2.0 * var_p) - 0.5
    return terms


def kl_diagonal_gaussians(mu_q: Tensor, log_sigma_q: Tensor, mu_p: Tensor, log_sigma_p: Tensor) -> Tensor:
    """KL(q || p) per row for diagonal Gaussians given as ``[N, L]`` mean and log std; shape ``[N]``.

    ``sum_l log(s_p/s_q) + (s_q^2 + (mu_q - mu_p)^2) / (2 s_p^2) - 1/2``.
    """
    return kl_per_dimension(mu_q, log_sigma_q, mu_p, log_sigma_p).sum(dim=1)


def free_bits_kl(kl_rows_dims: Tensor, free_bits: float) -> Tensor:
    """The loss's KL term from per-row, per-dimension KLs ``[N, L]``: ``sum_l max(mean_n kl[n, l], free_bits)``.

    With ``free_bits = 0`` this is the plain batch-mean KL (summed over dimensions).
    """
    per_dim = kl_rows_dims.mean(dim=0)
    if free_bits > 0:
        per_dim = torch.clamp(per_dim, min=free_bits)
    return per_dim.sum()


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
    #: The true KL (batch mean, summed over latent dimensions), whatever ``free_bits`` is.
    kl: Tensor
    reg: Tensor
    #: The KL term the loss used (``kl`` floored per dimension by ``free_bits``; ``kl`` without).
    kl_term: Tensor


def training_loss(
    model: ProbabilisticUNet,
    past: Tensor,
    target: Tensor,
    eps: Tensor,
    beta: float,
    weight_decay: float,
    free_bits: float = 0.0,
) -> LossTerms:
    """Forward pass and loss of one batch (see the module doc for the exact definition).

    ``free_bits``: nats per latent dimension below which a dimension's batch-mean KL is not
    pushed further (0: off).
    """
    prediction, (mu_q, ls_q), (mu_p, ls_p) = model(past, target, eps)
    mse = torch.mean((prediction - target) ** 2)
    kl_dims = kl_per_dimension(mu_q, ls_q, mu_p, ls_p)
    kl = kl_dims.sum(dim=1).mean()
    kl_term = free_bits_kl(kl_dims, free_bits) if free_bits > 0 else kl
    reg = weight_norm(model)
    return LossTerms(total=mse + beta * kl_term + weight_decay * reg, mse=mse, kl=kl, reg=reg, kl_term=kl_term)
