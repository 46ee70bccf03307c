"""Python tools for vamos, the Visual Anomaly MOnitoring Service.

The base package has no third-party dependencies. Sub-packages:

- :mod:`vamos.bundle`: read, write and verify model bundles (``*.vamos``), stdlib only.
- :mod:`vamos.train`: train the flow predictor and export bundles
  (``pip install vamos-client[train]``: torch, numpy, tqdm, onnx, onnxruntime).

The contract between training and the Rust server is ``docs/model-bundle.md``.
"""

__version__ = "0.1.0"

__all__ = ["__version__"]
