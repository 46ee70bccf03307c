"""Python tools for vamos, the Visual Anomaly MOnitoring Service.

``pip install clients/python`` installs the clients (grpcio, protobuf, httpx, mcap);
the rest are extras. Sub-packages:

- :mod:`vamos.client`: gRPC sessions and REST administration, blocking and asyncio, and
  the ``vamos-client`` command.
- :mod:`vamos.bundle`: read, write and verify model bundles (``*.vamos``), stdlib only.
- :mod:`vamos.train`: train the flow predictor and export bundles
  (``pip install 'vamos-client[train]'``: torch, numpy, tqdm, onnx, onnxruntime).
- :mod:`vamos.sim`: simulated episodes (``pip install 'vamos-client[sim]'``).
- :mod:`vamos.v1`: the generated gRPC stubs.
- :mod:`vamos.ros`: a shim over the ROS 2 package ``vamos_bridge`` (``clients/ros2``).

The contract between training and the Rust server is ``docs/model-bundle.md``.
"""

__version__ = "0.1.0"

__all__ = ["__version__"]
