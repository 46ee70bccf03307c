"""The committed tiny trained bundle (tests/fixtures/model) agrees with its reference outputs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from vamos.bundle import read_bundle
from vamos.train.export import run_bundle

FIXTURES = Path(__file__).resolve().parents[3] / "tests" / "fixtures" / "model"


@pytest.mark.skipif(not (FIXTURES / "tiny_trained.vamos").exists(), reason="repository fixtures not present")
def test_committed_fixture_matches_reference() -> None:
    bundle = FIXTURES / "tiny_trained.vamos"
    manifest = read_bundle(bundle).manifest
    assert manifest["architecture"]["filters"] == [8, 16, 16, 16]
    assert manifest["architecture"]["latent_dim"] == 6
    ref = dict(np.load(FIXTURES / "tiny_trained_reference.npz"))
    assert ref["flow"].shape == (2, 2, 64, 64) and ref["features"].shape == (2, 8, 64, 64)
    assert all(v.dtype == np.float32 for v in ref.values())
    np.testing.assert_allclose(ref["z"], ref["prior_mu"] + np.exp(ref["prior_log_sigma"]) * ref["eps"], atol=1e-6)
    got = run_bundle(bundle, ref["flow"], ref["z"])
    for key, ref_key in (("features", "features"), ("prior_mu", "prior_mu"),
                         ("prior_log_sigma", "prior_log_sigma"), ("flow", "head_flow")):
        np.testing.assert_allclose(got[key], ref[ref_key], atol=1e-5, err_msg=key)
    # The prediction is not trivial: it varies over the image.
    assert float(ref["head_flow"].std()) > 1e-3
