"""The probabilistic U-Net flow predictor (Kohl et al. 2018, as configured by the paper).

Structure (REFERENCE.md section 3), for ``filters = (32, 64, 128, 192)``:

- :class:`Encoder`: one level per filter entry; every level but the first starts with 2x2
  average pooling; each level is ``convs_per_level`` conv3x3 (padding 1) + ReLU; no norm.
- :class:`UNet`: the encoder on the past flow, then a decoder that per level upsamples x2
  (bilinear, ``align_corners=True``), concatenates ``[upsampled, skip]`` on channels and
  applies ``convs_per_level`` conv3x3 + ReLU. The output is the last decoder map,
  ``filters[0]`` channels at full resolution (no final 1x1).
- :class:`LatentNet`: an encoder of the same structure, global spatial mean of its deepest
  map, a 1x1 conv to ``2 * latent_dim`` values: ``mu`` then ``log_sigma`` (natural log of
  the standard deviation). The prior sees the past flow (2 channels), the posterior the
  past and target flow (4 channels, ``[past, target]``).
- :class:`Fcomb`: tile ``z`` over the map, concatenate ``[features, z]``, ``fcomb_layers``
  1x1 conv + ReLU, a final 1x1 conv to 2 channels with a linear output.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from vamos.train.config import ModelConfig


def _conv_block(in_channels: int, out_channels: int, convs: int) -> nn.Sequential:
    layers: list[nn.Module] = []
    channels = in_channels
    for _ in range(convs):
        layers.append(nn.Conv2d(channels, out_channels, kernel_size=3, padding=1))
        layers.append(nn.ReLU())
        channels = out_channels
    return nn.Sequential(*layers)


class Encoder(nn.Module):
    """Contracting path: returns the output map of every level, finest first."""

    def __init__(self, in_channels: int, filters: tuple[int, ...], convs_per_level: int) -> None:
        super().__init__()
        blocks = []
        channels = in_channels
        for width in filters:
            blocks.append(_conv_block(channels, width, convs_per_level))
            channels = width
        self.levels = nn.ModuleList(blocks)

    def forward(self, x: Tensor) -> list[Tensor]:
        """Maps of all levels; level ``i`` has resolution ``size / 2**i``."""
        maps = []
        for i, level in enumerate(self.levels):
            if i > 0:
                x = F.avg_pool2d(x, kernel_size=2, stride=2)
            x = level(x)
            maps.append(x)
        return maps


class UNet(nn.Module):
    """U-Net without a final 1x1: ``[N, in, S, S] -> [N, filters[0], S, S]``."""

    def __init__(self, in_channels: int, filters: tuple[int, ...], convs_per_level: int) -> None:
        super().__init__()
        self.encoder = Encoder(in_channels, filters, convs_per_level)
        blocks = []
        # Decoder levels from the second-deepest up to the finest.
        for i in reversed(range(len(filters) - 1)):
            blocks.append(_conv_block(filters[i + 1] + filters[i], filters[i], convs_per_level))
        self.decoder = nn.ModuleList(blocks)

    def forward(self, x: Tensor) -> Tensor:
        """Last decoder map."""
        maps = self.encoder(x)
        y: Tensor = maps[-1]
        for block, skip in zip(self.decoder, reversed(maps[:-1]), strict=True):
            y = F.interpolate(y, scale_factor=2.0, mode="bilinear", align_corners=True)
            y = block(torch.cat([y, skip], dim=1))
        return y


class LatentNet(nn.Module):
    """Prior or posterior net: diagonal Gaussian parameters ``(mu, log_sigma)``, each ``[N, L]``."""

    def __init__(
        self, in_channels: int, filters: tuple[int, ...], convs_per_level: int, latent_dim: int
    ) -> None:
        super().__init__()
        self.latent_dim = latent_dim
        self.encoder = Encoder(in_channels, filters, convs_per_level)
        self.to_params = nn.Conv2d(filters[-1], 2 * latent_dim, kernel_size=1)

    def forward(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """``(mu, log_sigma)`` of the latent Gaussian."""
        deepest = self.encoder(x)[-1]
        pooled = deepest.mean(dim=(2, 3), keepdim=True)
        params = torch.flatten(self.to_params(pooled), 1)
        return params[:, : self.latent_dim], params[:, self.latent_dim :]


class Fcomb(nn.Module):
    """Combines U-Net features and a latent sample into the predicted flow."""

    def __init__(
        self, feature_channels: int, latent_dim: int, width: int, layers: int, out_channels: int, size: int
    ) -> None:
        super().__init__()
        self.size = size
        modules: list[nn.Module] = []
        channels = feature_channels + latent_dim
        for _ in range(layers):
            modules.append(nn.Conv2d(channels, width, kernel_size=1))
            modules.append(nn.ReLU())
            channels = width
        modules.append(nn.Conv2d(channels, out_channels, kernel_size=1))
        self.layers = nn.Sequential(*modules)

    def forward(self, features: Tensor, z: Tensor) -> Tensor:
        """``features [N, C, S, S]``, ``z [N, L]`` -> flow ``[N, 2, S, S]``."""
        tiled = z[:, :, None, None].repeat(1, 1, self.size, self.size)
        flow: Tensor = self.layers(torch.cat([features, tiled], dim=1))
        return flow


class ProbabilisticUNet(nn.Module):
    """U-Net + prior net + posterior net + fcomb."""

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        self.config = config
        c = config
        self.unet = UNet(c.input_channels, c.filters, c.convs_per_level)
        self.prior = LatentNet(c.input_channels, c.filters, c.convs_per_level, c.latent_dim)
        self.posterior = LatentNet(2 * c.input_channels, c.filters, c.convs_per_level, c.latent_dim)
        self.fcomb = Fcomb(
            c.feature_channels, c.latent_dim, c.fcomb_width, c.fcomb_layers, c.input_channels, c.input_size
        )

    def forward(
        self, past: Tensor, target: Tensor, eps: Tensor
    ) -> tuple[Tensor, tuple[Tensor, Tensor], tuple[Tensor, Tensor]]:
        """Training forward pass.

        ``z = mu_q + exp(log_sigma_q) * eps`` is drawn from the posterior (reparameterised)
        with the caller's noise ``eps [N, L]``. Returns the prediction and the posterior
        and prior parameters ``(mu, log_sigma)``.
        """
        features = self.unet(past)
        prior = self.prior(past)
        posterior = self.posterior(torch.cat([past, target], dim=1))
        z = posterior[0] + torch.exp(posterior[1]) * eps
        return self.fcomb(features, z), posterior, prior

    def predict(self, past: Tensor, eps: Tensor) -> Tensor:
        """Inference: one prediction per row with ``z`` drawn from the prior with noise ``eps``."""
        mu, log_sigma = self.prior(past)
        flow: Tensor = self.fcomb(self.unet(past), mu + torch.exp(log_sigma) * eps)
        return flow


class EncoderGraph(nn.Module):
    """What ``encoder.onnx`` computes: ``flow -> (features, prior_mu, prior_log_sigma)``."""

    def __init__(self, model: ProbabilisticUNet) -> None:
        super().__init__()
        self.unet = model.unet
        self.prior = model.prior

    def forward(self, flow: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """U-Net features and prior parameters of a past flow."""
        mu, log_sigma = self.prior(flow)
        return self.unet(flow), mu, log_sigma


class HeadGraph(nn.Module):
    """What ``head.onnx`` computes: ``(features, z) -> flow``."""

    def __init__(self, model: ProbabilisticUNet) -> None:
        super().__init__()
        self.fcomb = model.fcomb

    def forward(self, features: Tensor, z: Tensor) -> Tensor:
        """Predicted flow."""
        flow: Tensor = self.fcomb(features, z)
        return flow


def count_parameters(module: nn.Module) -> int:
    """Number of trainable scalars in ``module``."""
    return sum(p.numel() for p in module.parameters() if p.requires_grad)


def parameter_counts(model: ProbabilisticUNet) -> dict[str, int]:
    """Parameter counts: per part, ``total`` and ``inference`` (U-Net + prior + fcomb)."""
    parts = {
        "unet": count_parameters(model.unet),
        "prior": count_parameters(model.prior),
        "posterior": count_parameters(model.posterior),
        "fcomb": count_parameters(model.fcomb),
    }
    parts["total"] = parts["unet"] + parts["prior"] + parts["posterior"] + parts["fcomb"]
    parts["inference"] = parts["unet"] + parts["prior"] + parts["fcomb"]
    return parts
