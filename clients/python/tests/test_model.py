"""Network structure: shapes, parameter counts, the torch-free base package."""

from __future__ import annotations

import subprocess
import sys

import pytest
import torch

from vamos.train.config import ConfigError, ModelConfig
from vamos.train.model import ProbabilisticUNet, parameter_counts


def conv_params(cin: int, cout: int, k: int) -> int:
    return cin * cout * k * k + cout


def expected_counts(filters: list[int], latent: int, in_ch: int = 2, convs: int = 3) -> dict[str, int]:
    """Parameter counts derived by hand from REFERENCE.md section 3."""

    def encoder(cin: int) -> int:
        total, c = 0, cin
        for f in filters:
            total += conv_params(c, f, 3) + (convs - 1) * conv_params(f, f, 3)
            c = f
        return total

    decoder = sum(
        conv_params(filters[i + 1] + filters[i], filters[i], 3) + (convs - 1) * conv_params(filters[i], filters[i], 3)
        for i in range(len(filters) - 1)
    )
    head = conv_params(filters[-1], 2 * latent, 1)
    c = filters[0]
    fcomb = conv_params(c + latent, c, 1) + 2 * conv_params(c, c, 1) + conv_params(c, 2, 1)
    unet = encoder(in_ch) + decoder
    prior = encoder(in_ch) + head
    posterior = encoder(2 * in_ch) + head
    return {"unet": unet, "prior": prior, "posterior": posterior, "fcomb": fcomb,
            "total": unet + prior + posterior + fcomb, "inference": unet + prior + fcomb}


def test_paper_parameter_counts() -> None:
    counts = parameter_counts(ProbabilisticUNet(ModelConfig()))
    print(f"paper-size parameter counts: {counts}")
    assert counts == expected_counts([32, 64, 128, 192], 6)
    # The paper: about 5.0 M in all, 3.6 M at inference.
    assert abs(counts["total"] - 5.0e6) < 0.05e6
    assert abs(counts["inference"] - 3.6e6) < 0.05e6


def test_half_width_parameter_counts() -> None:
    counts = parameter_counts(ProbabilisticUNet(ModelConfig(filters=(16, 32, 64, 96))))
    print(f"half-width parameter counts: {counts}")
    assert counts == expected_counts([16, 32, 64, 96], 6)


def test_shapes(tiny_model_config: ModelConfig) -> None:
    torch.manual_seed(0)
    model = ProbabilisticUNet(tiny_model_config)
    past = torch.rand(3, 2, 64, 64) - 0.5
    target = torch.rand(3, 2, 64, 64) - 0.5
    prediction, (mu_q, ls_q), (mu_p, ls_p) = model(past, target, torch.randn(3, 3))
    assert prediction.shape == (3, 2, 64, 64)
    for t in (mu_q, ls_q, mu_p, ls_p):
        assert t.shape == (3, 3)
    assert model.unet(past).shape == (3, 4, 64, 64)
    # The prior sees only the past: changing the target changes the posterior, not the prior.
    _, (mu_q2, _), (mu_p2, _) = model(past, target + 0.1, torch.randn(3, 3))
    assert torch.equal(mu_p, mu_p2)
    assert not torch.equal(mu_q, mu_q2)


def test_fcomb_tiles_z_per_sample(tiny_model_config: ModelConfig) -> None:
    """Each row's prediction depends on its own z only, identically at every pixel's input."""
    torch.manual_seed(0)
    model = ProbabilisticUNet(tiny_model_config)
    features = torch.rand(2, 4, 64, 64)
    z = torch.randn(2, 3)
    both = model.fcomb(features, z)
    first = model.fcomb(features[:1], z[:1])
    assert torch.allclose(both[:1], first, atol=1e-6)
    # Hand-tiled reference through the same layers.
    tiled = torch.cat([features, z[:, :, None, None].expand(2, 3, 64, 64)], dim=1)
    assert torch.allclose(model.fcomb.layers(tiled), both, atol=1e-6)


def test_bad_config_is_an_error() -> None:
    with pytest.raises(ConfigError) as err:
        ModelConfig(filters=(8, 16, 32, 64), input_size=20)
    assert err.value.field_name == "input_size"
    with pytest.raises(ConfigError):
        ModelConfig(latent_dim=0)


def test_base_package_imports_without_torch() -> None:
    code = (
        "import sys; sys.modules['torch'] = None; sys.modules['numpy'] = None\n"
        "import vamos, vamos.bundle, vamos.train\n"
        "print(vamos.__version__)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env={"PYTHONPATH": vamos_src()})
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "0.1.0"


def vamos_src() -> str:
    import vamos

    return str(__import__("pathlib").Path(vamos.__file__).parent.parent)
