"""Small deterministic synthetic datasets in the contract format (tests, demos, fixtures).

Each episode is a smooth flow field that translates over time: per channel
``amplitude * sin(kx * (x - vx * t) + ky * (y - vy * t) + phase)`` with per-episode random
wave vectors, velocities and phases, plus Gaussian noise, clipped to [-0.5, 0.5]. A
network can learn to predict ``O_t`` from ``O_{t-n}`` only partly (``n`` is unknown to it),
which is the situation of the real data.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np


def synthetic_episode(rng: np.random.Generator, frames: int, size: int, noise: float) -> np.ndarray:
    """One episode's flows, float32 ``[frames, 2, size, size]``."""
    y, x = np.mgrid[0:size, 0:size].astype(np.float64) / size
    out = np.empty((frames, 2, size, size), dtype=np.float32)
    params = []
    for _ in range(2):
        k = rng.uniform(1.0, 3.0, 2) * 2 * np.pi * rng.choice([-1.0, 1.0], 2)
        velocity = rng.uniform(-0.03, 0.03, 2)
        params.append((k, velocity, rng.uniform(0, 2 * np.pi), rng.uniform(0.15, 0.35)))
    for t in range(frames):
        for c, (k, velocity, phase, amplitude) in enumerate(params):
            field = amplitude * np.sin(k[0] * (x - velocity[0] * t) + k[1] * (y - velocity[1] * t) + phase)
            out[t, c] = field + rng.normal(0.0, noise, field.shape)
    return np.clip(out, -0.5, 0.5)


def write_synthetic_dataset(
    path: str | Path,
    episodes: int = 4,
    frames: int = 20,
    size: int = 64,
    seed: int = 0,
    noise: float = 0.01,
    flow_variant: str = "plain",
) -> Path:
    """Write ``episodes`` synthetic episodes of ``frames`` rows to ``path`` (manifest + .npy)."""
    root = Path(path)
    root.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    entries = []
    for i in range(episodes):
        name = f"ep{i:04d}"
        flows = synthetic_episode(rng, frames, size, noise)
        np.save(root / f"{name}.npy", flows)
        entries.append({
            "name": name,
            "file": f"{name}.npy",
            "frames": [{"index": 1 + k, "stamp_ns": (1 + k) * 100_000_000} for k in range(frames)],
        })
    manifest = {
        "format": "vamos-dataset",
        "format_version": 1,
        "input": {"size": size, "clip_px": 15.0, "reference_width_px": 640},
        "flow_variant": flow_variant,
        "processing": {"width": 640, "height": 480, "stride": 1},
        "episodes": entries,
    }
    (root / "manifest.json").write_text(json.dumps(manifest, indent=2) + "\n")
    return root
