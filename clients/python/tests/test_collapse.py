"""The posterior-collapse check: measured numbers on hand-set networks, and its place in a run."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from conftest import TINY_FILTERS, fixed_latents, tiny_fit_config
from vamos.train.collapse import collapse_check, collapse_summary, collapse_warning
from vamos.train.config import ConfigError, ModelConfig
from vamos.train.data import PairSampler, load_dataset
from vamos.train.model import ProbabilisticUNet
from vamos.train.trainer import fit, load_checkpoint


def _sampler(dataset: Path) -> PairSampler:
    return PairSampler(load_dataset(str(dataset)).episodes, a=5, b=4)


def _check(model: ProbabilisticUNet, sampler: PairSampler, samples: int = 4):
    return collapse_check(model, sampler, np.random.default_rng(0), torch.Generator().manual_seed(0),
                          samples=samples, batch_size=8, device=torch.device("cpu"), split="validation")


def test_a_posterior_equal_to_the_prior_is_collapsed(tiny_dataset: Path) -> None:
    torch.manual_seed(0)
    model = ProbabilisticUNet(ModelConfig(filters=TINY_FILTERS, latent_dim=3))
    fixed_latents(model, [0.0, 0.0, 0.0])
    check = _check(model, _sampler(tiny_dataset))
    assert check.pairs == 25 and check.samples == 4
    assert abs(check.kl) < 1e-9 and check.collapsed
    assert any("KL(posterior || prior)" in r for r in check.reasons)
    warning = collapse_warning(check)
    assert warning is not None and "--free-bits" in warning
    assert check.mse_best_of_samples <= check.mse


def test_an_informative_posterior_is_not_collapsed(tiny_dataset: Path) -> None:
    torch.manual_seed(0)
    model = ProbabilisticUNet(ModelConfig(filters=TINY_FILTERS, latent_dim=3))
    # KL per dimension of N(mu, 1) || N(0, 1) is mu^2 / 2: 0.5 + 0.125 + 0 nats.
    fixed_latents(model, [1.0, 0.5, 0.0])
    check = _check(model, _sampler(tiny_dataset))
    assert check.kl == pytest.approx(0.625, abs=1e-6)
    assert check.kl_per_dim == pytest.approx([0.5, 0.125, 0.0], abs=1e-6)
    # A freshly initialised fcomb uses z: the prior's samples spread.
    assert check.sample_spread > 0 and check.spread_ratio is not None
    assert check.spread_ratio == pytest.approx(check.sample_spread / math.sqrt(check.mse))
    assert not check.collapsed and collapse_warning(check) is None
    # The best of several samples is never worse than their mean error.
    assert check.mse_best_of_samples < check.mse
    assert "KL(posterior || prior) 0.625 nats" in collapse_summary(check)
    assert json.loads(json.dumps(check.to_dict()))["kl"] == pytest.approx(0.625, abs=1e-6)


def test_a_network_that_ignores_z_is_collapsed_by_spread(tiny_dataset: Path) -> None:
    torch.manual_seed(0)
    model = ProbabilisticUNet(ModelConfig(filters=TINY_FILTERS, latent_dim=3))
    fixed_latents(model, [1.0, 1.0, 1.0])  # KL 1.5 nats: not collapsed by KL
    with torch.no_grad():  # ... but fcomb's first layer no longer reads the latent channels
        first = next(m for m in model.fcomb.modules() if isinstance(m, torch.nn.Conv2d))
        first.weight[:, -3:].zero_()
    check = _check(model, _sampler(tiny_dataset))
    assert check.kl == pytest.approx(1.5, abs=1e-6)
    assert check.sample_spread == pytest.approx(0.0, abs=1e-9)
    assert check.collapsed and any("sample spread" in r for r in check.reasons)
    assert check.mse_best_of_samples == pytest.approx(check.mse, rel=1e-9)


def test_bad_arguments_are_refused(tiny_dataset: Path) -> None:
    model = ProbabilisticUNet(ModelConfig(filters=TINY_FILTERS, latent_dim=3))
    with pytest.raises(ValueError, match="at least 2 prior samples"):
        _check(model, _sampler(tiny_dataset), samples=1)
    with pytest.raises(ValueError, match="no pairs"):
        _check(model, PairSampler([], a=5, b=4))


def test_a_run_records_its_collapse_check_and_beta_schedule(tiny_dataset: Path, tmp_path: Path) -> None:
    cfg = tiny_fit_config(tiny_dataset, tmp_path / "run", epochs=3)
    cfg.free_bits = 0.05
    cfg.kl_warmup_epochs = 2
    result = fit(cfg)
    assert [r["beta"] for r in result.history] == [0.0, 5.0, 10.0]
    assert result.collapse is not None and result.collapse["split"] == "validation"
    assert result.collapse["pairs"] == 5 and result.collapse["samples"] >= 2
    assert load_checkpoint(tmp_path / "run" / "checkpoints" / "last.pt")["collapse_check"] == result.collapse
    training = result.manifest["training"]
    assert training["free_bits"] == 0.05 and training["kl_warmup_epochs"] == 2
    assert training["collapse_check"] == result.collapse


def test_bad_schedules_are_refused(tiny_dataset: Path, tmp_path: Path) -> None:
    cfg = tiny_fit_config(tiny_dataset, tmp_path / "bad", epochs=1)
    cfg.free_bits = -0.1
    with pytest.raises(ConfigError, match="free_bits"):
        cfg.validate()
    cfg.free_bits = 0.0
    cfg.kl_warmup_epochs = -1
    with pytest.raises(ConfigError, match="kl_warmup_epochs"):
        cfg.validate()
