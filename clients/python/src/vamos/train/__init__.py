"""Training of the vamos flow predictor (probabilistic U-Net) and bundle export.

Needs the ``train`` extra (torch, numpy, tqdm, onnx, onnxruntime). Modules:

- :mod:`vamos.train.config`: :class:`ModelConfig` (architecture) and :class:`FitConfig`.
- :mod:`vamos.train.model`: the probabilistic U-Net (Kohl et al. 2018) as in the paper.
- :mod:`vamos.train.losses`: MSE, analytic KL, weight-norm regulariser, total loss.
- :mod:`vamos.train.data`: dataset reading, episode split, time-agnostic pair sampling.
- :mod:`vamos.train.trainer`: the training loop, checkpoints and resume.
- :mod:`vamos.train.export`: ONNX export, bundle manifest, onnxruntime verification.
- :mod:`vamos.train.cli`: the ``vamos-train`` command.

Importing this package does not import torch; the sub-modules do.
"""
