"""The posterior-collapse check run after training.

A probabilistic U-Net whose posterior has collapsed onto its prior (KL(posterior || prior)
near 0) learns to ignore ``z``: the ``M`` prior samples the server draws per past offset
then give the same prediction, and its minimum over samples (``e_o``, docs/model-bundle.md)
buys nothing over one sample. :func:`collapse_check` measures, on a set of pairs:

- ``kl``: the mean over pairs of KL(posterior || prior), nats, summed over the latent
  dimensions (the true KL, as in ``log.jsonl``; free bits do not enter it), and
  ``kl_per_dim``, its split over the latent dimensions;
- ``sample_spread``: the mean over pairs, channels and pixels of the per-pixel standard
  deviation (``correction=1``) across ``samples`` prior samples of the predicted flow, in
  network units (the flow scaled by ``0.5 / clip_px``), the units of ``sqrt(mse)``;
- ``mse``: the mean squared error of the prior-sampled predictions (all samples), and
  ``mse_best_of_samples``: the mean over pairs of the smallest per-pair mean squared error
  among the samples (the server's minimum over samples at the true offset);
- ``spread_ratio`` = ``sample_spread / sqrt(mse)``.

The run counts as collapsed when ``kl < KL_COLLAPSE_NATS`` (1e-3 nats) or
``spread_ratio < SPREAD_COLLAPSE_RATIO`` (1 %); :func:`collapse_warning` words it.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import torch

from vamos.train.data import PairSampler
from vamos.train.losses import kl_per_dimension
from vamos.train.model import ProbabilisticUNet

#: A KL (nats, summed over latent dimensions, mean over pairs) below this counts as collapsed.
KL_COLLAPSE_NATS = 1e-3
#: A sample spread below this fraction of ``sqrt(mse)`` counts as negligible.
SPREAD_COLLAPSE_RATIO = 0.01


@dataclass
class CollapseCheck:
    """Result of :func:`collapse_check` (plain numbers; ``None`` where undefined)."""

    #: Which pairs were measured: ``"validation"`` or ``"train"`` (no validation split).
    split: str
    #: Number of ``(past, target)`` pairs.
    pairs: int
    #: Prior samples per pair.
    samples: int
    #: Mean KL(posterior || prior), nats, summed over latent dimensions.
    kl: float
    #: Mean KL per latent dimension, nats.
    kl_per_dim: list[float]
    #: Mean per-pixel standard deviation of the prediction across prior samples (network units).
    sample_spread: float
    #: Mean squared error of the prior-sampled predictions.
    mse: float
    #: Mean over pairs of the smallest per-pair mean squared error among the samples.
    mse_best_of_samples: float
    #: ``sample_spread / sqrt(mse)`` (``None`` when ``mse`` is 0).
    spread_ratio: float | None
    #: Whether either criterion flags collapse.
    collapsed: bool = False
    #: The criteria that fired, in words.
    reasons: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON form (strict JSON: no NaN)."""
        out = asdict(self)
        for key, value in out.items():
            if isinstance(value, float) and not math.isfinite(value):
                out[key] = None
        return out


def _judge(check: CollapseCheck) -> None:
    reasons = []
    if check.kl < KL_COLLAPSE_NATS:
        reasons.append(f"KL(posterior || prior) {check.kl:.3g} nats < {KL_COLLAPSE_NATS:g}")
    if check.spread_ratio is not None and check.spread_ratio < SPREAD_COLLAPSE_RATIO:
        reasons.append(f"sample spread {check.sample_spread:.3g} is {100 * check.spread_ratio:.3g} % of "
                       f"sqrt(mse) {math.sqrt(check.mse):.3g} (< {100 * SPREAD_COLLAPSE_RATIO:g} %)")
    check.collapsed = bool(reasons)
    check.reasons = reasons


def collapse_check(
    model: ProbabilisticUNet,
    sampler: PairSampler,
    rng: np.random.Generator,
    generator: torch.Generator,
    samples: int,
    batch_size: int,
    device: torch.device,
    split: str,
    channels_last: bool = False,
) -> CollapseCheck:
    """Measure KL and prior-sample spread on every valid target of ``sampler`` (in order,
    offsets drawn from ``rng``, latent noise from ``generator``); see the module doc."""
    if samples < 2:
        raise ValueError(f"need at least 2 prior samples to measure their spread, got {samples}")
    if len(sampler) == 0:
        raise ValueError("no pairs to measure")
    model.eval()
    plan = sampler.plan(rng, shuffle=False)
    latent = model.config.latent_dim
    kl_dims_sum = torch.zeros(latent, dtype=torch.float64)
    spread_sum = mse_sum = best_sum = 0.0
    with torch.no_grad():
        for start in range(0, len(plan), batch_size):
            past_np, target_np = sampler.gather(plan, start, start + batch_size)
            past = torch.from_numpy(past_np).to(device)
            target = torch.from_numpy(target_np).to(device)
            if channels_last:
                past = past.contiguous(memory_format=torch.channels_last)
                target = target.contiguous(memory_format=torch.channels_last)
            count = past.shape[0]
            features = model.unet(past)
            mu_p, ls_p = model.prior(past)
            mu_q, ls_q = model.posterior(torch.cat([past, target], dim=1))
            kl_dims_sum += kl_per_dimension(mu_q, ls_q, mu_p, ls_p).double().sum(dim=0).cpu()
            eps = torch.randn(samples, count, latent, generator=generator).to(device)
            predictions = torch.stack([model.fcomb(features, mu_p + torch.exp(ls_p) * eps[s])
                                       for s in range(samples)])  # [M, B, 2, S, S]
            spread = predictions.double().std(dim=0, correction=1)  # [B, 2, S, S]
            spread_sum += float(spread.mean(dim=(1, 2, 3)).sum())
            errors = ((predictions - target.unsqueeze(0)) ** 2).double().mean(dim=(2, 3, 4))  # [M, B]
            mse_sum += float(errors.mean(dim=0).sum())
            best_sum += float(errors.min(dim=0).values.sum())
    pairs = len(plan)
    kl_per_dim = [float(v) / pairs for v in kl_dims_sum]
    mse = mse_sum / pairs
    spread_mean = spread_sum / pairs
    check = CollapseCheck(
        split=split, pairs=pairs, samples=samples, kl=sum(kl_per_dim), kl_per_dim=kl_per_dim,
        sample_spread=spread_mean, mse=mse, mse_best_of_samples=best_sum / pairs,
        spread_ratio=spread_mean / math.sqrt(mse) if mse > 0 else None,
    )
    _judge(check)
    return check


def collapse_summary(check: CollapseCheck) -> str:
    """One line with the measured numbers."""
    ratio = "n/a" if check.spread_ratio is None else f"{100 * check.spread_ratio:.3g} % of sqrt(mse)"
    return (f"collapse check ({check.split}, {check.pairs} pairs, {check.samples} prior samples each): "
            f"KL(posterior || prior) {check.kl:.4g} nats, sample spread {check.sample_spread:.4g} ({ratio}), "
            f"mse {check.mse:.4g}, best-of-{check.samples} mse {check.mse_best_of_samples:.4g}")


def collapse_warning(check: CollapseCheck) -> str | None:
    """The warning for a collapsed run, or ``None``."""
    if not check.collapsed:
        return None
    return ("warning: posterior collapse: " + "; ".join(check.reasons) + ". The prior's samples give "
            "practically the same prediction, so the server's minimum over samples buys nothing: its "
            "`samples` (M) could be 1 at no loss. To keep z informative, retrain with --free-bits "
            "(e.g. 0.1 nats per latent dimension) and/or --kl-warmup-epochs (e.g. 10), or a smaller --beta.")
