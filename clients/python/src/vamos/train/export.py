"""Export a trained (or untrained) model to a model bundle and verify it with onnxruntime.

``encoder.onnx`` holds U-Net + prior (``flow -> features, prior_mu, prior_log_sigma``),
``head.onnx`` holds fcomb (``features, z -> flow``); batch axis ``N`` dynamic, opset 17,
default domain only, no random operators (docs/model-bundle.md). The graphs are produced
by torch's TorchScript-based exporter (``dynamo=False``): it writes opset 17 directly,
while the dynamo exporter only down-converts from 18 and fails on ReduceMean here.
"""

from __future__ import annotations

import datetime as _dt
import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import onnx
import torch

from vamos.bundle import BUNDLE_FORMAT, BUNDLE_FORMAT_VERSION, read_bundle, write_bundle
from vamos.train.model import EncoderGraph, HeadGraph, ProbabilisticUNet, parameter_counts

#: ONNX opset of the bundle graphs.
OPSET = 17


class ExportError(RuntimeError):
    """An exported graph breaks the contract or disagrees with torch."""

    def __init__(self, member: str, reason: str) -> None:
        self.member = member
        self.reason = reason
        super().__init__(f"{member}: {reason}")


def _to_onnx(
    module: torch.nn.Module, args: tuple[torch.Tensor, ...], inputs: list[str], outputs: list[str]
) -> bytes:
    axes = {name: {0: "N"} for name in inputs + outputs}
    with warnings.catch_warnings(), tempfile.TemporaryDirectory() as tmp:
        warnings.simplefilter("ignore")
        target = Path(tmp) / "graph.onnx"
        torch.onnx.export(
            module,
            args,
            target,
            input_names=inputs,
            output_names=outputs,
            dynamic_axes=axes,
            opset_version=OPSET,
            do_constant_folding=True,
            dynamo=False,
        )
        data = target.read_bytes()
    check_graph(data, "export")
    return data


def check_graph(data: bytes, member: str) -> onnx.ModelProto:
    """Check an ONNX graph against the contract: valid, opset 17, default domain, no random ops."""
    model = onnx.load_from_string(data)
    onnx.checker.check_model(model)
    opsets = {o.domain: o.version for o in model.opset_import}
    if opsets.get("", opsets.get("ai.onnx")) != OPSET or any(d not in ("", "ai.onnx") for d in opsets):
        raise ExportError(member, f"opset imports {opsets}, expected only the default domain at {OPSET}")
    for node in model.graph.node:
        if node.domain not in ("", "ai.onnx"):
            raise ExportError(member, f"node {node.name} uses domain {node.domain!r}")
        if node.op_type.startswith("Random") or node.op_type in ("Multinomial", "Bernoulli", "Dropout"):
            raise ExportError(member, f"node {node.name} is a random operator ({node.op_type})")
    return model


def export_graphs(model: ProbabilisticUNet) -> tuple[bytes, bytes]:
    """``(encoder.onnx, head.onnx)`` bytes of a model (exported on CPU, eval mode)."""
    cfg = model.config
    model = model.to("cpu").eval()
    flow = torch.zeros(2, cfg.input_channels, cfg.input_size, cfg.input_size)
    features = torch.zeros(2, cfg.feature_channels, cfg.input_size, cfg.input_size)
    z = torch.zeros(2, cfg.latent_dim)
    with torch.no_grad():
        encoder = _to_onnx(EncoderGraph(model), (flow,), ["flow"], ["features", "prior_mu", "prior_log_sigma"])
        head = _to_onnx(HeadGraph(model), (features, z), ["features", "z"], ["flow"])
    return encoder, head


def architecture_entry(model: ProbabilisticUNet) -> dict[str, Any]:
    """The manifest's ``architecture`` object."""
    cfg = model.config
    counts = parameter_counts(model)
    return {
        "filters": list(cfg.filters),
        "convs_per_level": cfg.convs_per_level,
        "latent_dim": cfg.latent_dim,
        "feature_channels": cfg.feature_channels,
        "fcomb_channels": cfg.fcomb_width,
        "fcomb_layers": cfg.fcomb_layers,
        "parameters_total": counts["total"],
        "parameters_inference": counts["inference"],
    }


@dataclass
class BundleInfo:
    """Manifest fields that do not come from the network itself."""

    #: Model name.
    name: str
    #: ``input`` object minus ``size``/``channels``: ``clip_px`` and ``reference_width_px``.
    clip_px: float
    #: Width of the image the clip bound refers to, pixels.
    reference_width_px: int
    #: Flow variant the model was trained on.
    flow_variant: str
    #: ``processing`` object: ``width``, ``height``, ``stride``.
    processing: dict[str, int]
    #: ``temporal`` object: ``a``, ``b``, ``m``.
    temporal: dict[str, int]
    #: ``training`` object (summary of the run).
    training: dict[str, Any]
    #: ``created`` timestamp (RFC 3339 UTC); ``None`` means now.
    created: str | None = None


def build_manifest(model: ProbabilisticUNet, info: BundleInfo) -> dict[str, Any]:
    """Manifest without ``members`` (filled in by :func:`vamos.bundle.write_bundle`)."""
    created = info.created or _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
    cfg = model.config
    return {
        "format": BUNDLE_FORMAT,
        "format_version": BUNDLE_FORMAT_VERSION,
        "name": info.name,
        "created": created,
        "opset": OPSET,
        "architecture": architecture_entry(model),
        "input": {
            "size": cfg.input_size,
            "channels": cfg.input_channels,
            "clip_px": float(info.clip_px),
            "reference_width_px": int(info.reference_width_px),
        },
        "temporal": {k: int(info.temporal[k]) for k in ("a", "b", "m")},
        "flow_variant": info.flow_variant,
        "processing": {k: int(info.processing[k]) for k in ("width", "height", "stride")},
        "training": info.training,
    }


def export_bundle(model: ProbabilisticUNet, path: str | Path, info: BundleInfo, verify: bool = True) -> dict[str, Any]:
    """Export ``model`` to the bundle ``path``; returns the manifest as written.

    With ``verify`` (and onnxruntime installed) the written bundle is read back and its
    graphs are run against torch (:func:`verify_bundle`); a disagreement raises.
    """
    encoder, head = export_graphs(model)
    manifest = write_bundle(path, build_manifest(model, info), encoder, head)
    if verify and _have_onnxruntime():
        verify_bundle(path, model)
    return manifest


def _have_onnxruntime() -> bool:
    try:
        import onnxruntime  # noqa: F401
    except ImportError:
        return False
    return True


def run_bundle(
    path: str | Path, flow: np.ndarray, z: np.ndarray, threads: int = 1
) -> dict[str, np.ndarray]:
    """Run a bundle's two graphs with onnxruntime on CPU.

    ``flow [N, 2, S, S]`` through the encoder, then its ``features`` with ``z [N, L]`` through
    the head. Returns ``features``, ``prior_mu``, ``prior_log_sigma`` and ``flow``.
    """
    import onnxruntime as ort

    bundle = read_bundle(path)
    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    providers = ["CPUExecutionProvider"]
    encoder = ort.InferenceSession(bundle.encoder_onnx, options, providers=providers)
    head = ort.InferenceSession(bundle.head_onnx, options, providers=providers)
    features, mu, log_sigma = encoder.run(None, {"flow": flow.astype(np.float32)})
    (predicted,) = head.run(None, {"features": features, "z": z.astype(np.float32)})
    return {"features": features, "prior_mu": mu, "prior_log_sigma": log_sigma, "flow": predicted}


#: Largest allowed |onnxruntime - torch| in :func:`verify_bundle`.
VERIFY_TOLERANCE = 1e-4


def verify_bundle(
    path: str | Path, model: ProbabilisticUNet, batch: int = 3, seed: int = 0
) -> dict[str, float]:
    """Compare the bundle's graphs (onnxruntime) with ``model`` (torch, CPU) on random inputs.

    Inputs: ``batch`` flows uniform in [-0.5, 0.5] and standard-normal ``z``, from ``seed``.
    Returns the max abs difference per output; raises :class:`ExportError` if any exceeds
    :data:`VERIFY_TOLERANCE`.
    """
    cfg = model.config
    rng = np.random.default_rng(seed)
    flow = rng.uniform(-0.5, 0.5, (batch, cfg.input_channels, cfg.input_size, cfg.input_size)).astype(np.float32)
    z = rng.standard_normal((batch, cfg.latent_dim)).astype(np.float32)
    got = run_bundle(path, flow, z)
    model = model.to("cpu").eval()
    with torch.no_grad():
        features, mu, log_sigma = EncoderGraph(model)(torch.from_numpy(flow))
        predicted = HeadGraph(model)(features, torch.from_numpy(z))
    want = {"features": features, "prior_mu": mu, "prior_log_sigma": log_sigma, "flow": predicted}
    diffs = {k: float(np.max(np.abs(got[k] - want[k].numpy()))) for k in want}
    for name, diff in diffs.items():
        if not diff < VERIFY_TOLERANCE:
            raise ExportError(name, f"onnxruntime differs from torch by {diff:.3g} (> {VERIFY_TOLERANCE})")
    return diffs
