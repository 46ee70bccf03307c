"""Bundle export: ONNX contract, onnxruntime parity, manifest and checksums."""

from __future__ import annotations

import hashlib
import json
import zipfile
from pathlib import Path

import numpy as np
import onnx
import pytest
import torch

from vamos.bundle import BundleError, read_bundle
from vamos.train.config import ModelConfig
from vamos.train.export import BundleInfo, export_bundle, run_bundle, verify_bundle
from vamos.train.model import ProbabilisticUNet, parameter_counts

CONTRACT_KEYS = {"format", "format_version", "name", "created", "opset", "architecture", "input",
                 "temporal", "flow_variant", "processing", "training", "members"}
TRAINING_KEYS = {"episodes_train", "episodes_validation", "frames_train", "epochs", "batch_size",
                 "learning_rate", "beta", "weight_decay", "seed", "final_train_loss",
                 "final_validation_loss", "dataset"}


def info() -> BundleInfo:
    return BundleInfo(
        name="tiny", clip_px=15.0, reference_width_px=640, flow_variant="masked",
        processing={"width": 640, "height": 480, "stride": 3}, temporal={"a": 5, "b": 4, "m": 10},
        training={k: 0 for k in TRAINING_KEYS} | {"dataset": "test"}, created="2026-11-22T10:00:00Z",
    )


@pytest.fixture(scope="module")
def exported(tmp_path_factory: pytest.TempPathFactory) -> tuple[ProbabilisticUNet, Path, dict]:
    torch.manual_seed(5)
    model = ProbabilisticUNet(ModelConfig(filters=(4, 8, 8, 8), latent_dim=3))
    path = tmp_path_factory.mktemp("bundle") / "tiny.vamos"
    manifest = export_bundle(model, path, info(), verify=False)
    return model, path, manifest


def test_onnxruntime_matches_torch(exported: tuple[ProbabilisticUNet, Path, dict]) -> None:
    model, path, _ = exported
    diffs = verify_bundle(path, model, batch=4, seed=1)
    print(f"onnxruntime vs torch max abs diff: {diffs}")
    assert set(diffs) == {"features", "prior_mu", "prior_log_sigma", "flow"}
    assert max(diffs.values()) < 1e-4
    # And against the model's own inference path, at another batch size (dynamic N).
    rng = np.random.default_rng(9)
    flow = rng.uniform(-0.5, 0.5, (1, 2, 64, 64)).astype(np.float32)
    eps = rng.standard_normal((1, 3)).astype(np.float32)
    out = run_bundle(path, flow, np.zeros((1, 3), np.float32))
    z = out["prior_mu"] + np.exp(out["prior_log_sigma"]) * eps
    got = run_bundle(path, flow, z)["flow"]
    with torch.no_grad():
        want = model.eval().predict(torch.from_numpy(flow), torch.from_numpy(eps)).numpy()
    assert got.shape == (1, 2, 64, 64)
    assert float(np.abs(got - want).max()) < 1e-4


def test_graphs_follow_contract(exported: tuple[ProbabilisticUNet, Path, dict]) -> None:
    _, path, _ = exported
    bundle = read_bundle(path)
    for data, inputs, outputs in (
        (bundle.encoder_onnx, {"flow": ["N", 2, 64, 64]},
         {"features": ["N", 4, 64, 64], "prior_mu": ["N", 3], "prior_log_sigma": ["N", 3]}),
        (bundle.head_onnx, {"features": ["N", 4, 64, 64], "z": ["N", 3]}, {"flow": ["N", 2, 64, 64]}),
    ):
        graph = onnx.load_from_string(data)
        assert [(o.domain, o.version) for o in graph.opset_import] == [("", 17)]

        def shapes(values: list) -> dict[str, list]:
            return {v.name: [d.dim_param or d.dim_value for d in v.type.tensor_type.shape.dim] for v in values}

        assert shapes(graph.graph.input) == inputs
        assert shapes(graph.graph.output) == outputs
        for v in list(graph.graph.input) + list(graph.graph.output):
            assert v.type.tensor_type.elem_type == onnx.TensorProto.FLOAT
        ops = {n.op_type for n in graph.graph.node}
        assert not any(op.startswith("Random") for op in ops), ops
        assert all(n.domain == "" for n in graph.graph.node)


def test_manifest_and_checksums(exported: tuple[ProbabilisticUNet, Path, dict]) -> None:
    model, path, manifest = exported
    with zipfile.ZipFile(path) as archive:
        assert sorted(archive.namelist()) == ["encoder.onnx", "head.onnx", "manifest.json"]
        stored = json.loads(archive.read("manifest.json"))
        for member in ("encoder.onnx", "head.onnx"):
            assert stored["members"][member]["sha256"] == hashlib.sha256(archive.read(member)).hexdigest()
    assert stored == manifest
    assert set(stored) == CONTRACT_KEYS
    assert set(stored["training"]) == TRAINING_KEYS
    counts = parameter_counts(model)
    assert stored["architecture"] == {
        "filters": [4, 8, 8, 8], "convs_per_level": 3, "latent_dim": 3, "feature_channels": 4,
        "fcomb_channels": 4, "fcomb_layers": 3, "parameters_total": counts["total"],
        "parameters_inference": counts["inference"],
    }
    assert stored["input"] == {"size": 64, "channels": 2, "clip_px": 15.0, "reference_width_px": 640}
    assert stored["temporal"] == {"a": 5, "b": 4, "m": 10}
    assert stored["opset"] == 17 and stored["format"] == "vamos-model" and stored["format_version"] == 1


def test_tampered_bundle_is_refused(exported: tuple[ProbabilisticUNet, Path, dict], tmp_path: Path) -> None:
    _, path, _ = exported
    with zipfile.ZipFile(path) as archive:
        members = {n: archive.read(n) for n in archive.namelist()}
    bad = tmp_path / "bad.vamos"
    with zipfile.ZipFile(bad, "w") as archive:
        for name, data in members.items():
            archive.writestr(name, data + b"x" if name == "head.onnx" else data)
    with pytest.raises(BundleError, match="head.onnx: sha256"):
        read_bundle(bad)
    extra = tmp_path / "extra.vamos"
    with zipfile.ZipFile(extra, "w") as archive:
        for name, data in members.items():
            archive.writestr(name, data)
        archive.writestr("notes.txt", b"hi")
    with pytest.raises(BundleError, match="members"):
        read_bundle(extra)


def test_export_is_deterministic(exported: tuple[ProbabilisticUNet, Path, dict], tmp_path: Path) -> None:
    model, path, _ = exported
    again = tmp_path / "again.vamos"
    export_bundle(model, again, info(), verify=False)
    assert again.read_bytes() == path.read_bytes()
