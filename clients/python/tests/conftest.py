"""Shared fixtures: tiny synthetic datasets in the contract format."""

from __future__ import annotations

from pathlib import Path

import pytest

torch = pytest.importorskip("torch")

from vamos.train.config import ModelConfig, FitConfig  # noqa: E402
from vamos.train.model import ProbabilisticUNet  # noqa: E402
from vamos.train.synthetic import write_synthetic_dataset  # noqa: E402

#: Widths small enough for fast CPU tests.
TINY_FILTERS = (4, 8, 8, 8)


def fixed_latents(model: ProbabilisticUNet, posterior_mu: list[float]) -> None:
    """Prior N(0, 1) and posterior N(posterior_mu, 1) for every input (1x1 conv weights 0)."""
    latent = model.config.latent_dim
    with torch.no_grad():
        for net, mu in ((model.prior, [0.0] * latent), (model.posterior, posterior_mu)):
            net.to_params.weight.zero_()
            net.to_params.bias.copy_(torch.tensor(mu + [0.0] * latent))


@pytest.fixture(autouse=True)
def _few_threads() -> None:
    torch.set_num_threads(1)


@pytest.fixture(scope="session")
def tiny_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """5 episodes of 14 frames of 64x64 synthetic flow (5 valid targets each for a=5, b=4)."""
    return write_synthetic_dataset(tmp_path_factory.mktemp("dataset"), episodes=5, frames=14, seed=3)


@pytest.fixture
def tiny_model_config() -> ModelConfig:
    """A tiny network: filters 4,8,8,8, latent 3."""
    return ModelConfig(filters=TINY_FILTERS, latent_dim=3)


def tiny_fit_config(dataset: Path, run_dir: Path, epochs: int) -> FitConfig:
    """A fast training configuration on a tiny dataset."""
    return FitConfig(
        dataset_dir=str(dataset),
        run_dir=str(run_dir),
        model=ModelConfig(filters=TINY_FILTERS, latent_dim=3),
        epochs=epochs,
        batch_size=8,
        learning_rate=1e-3,
        val_fraction=0.2,
        seed=7,
        device="cpu",
        threads=1,
        progress=False,
    )
