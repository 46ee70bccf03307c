"""Seeded procedural textures (numpy), written as PNG for ``pybullet.loadTexture``.

Optical flow and image registration need texture everywhere, so every surface of the scene
gets one: value noise (wood, plaster, concrete), checkers (floor tiles), stripes (book
covers, fabric). The PNG writer is a small standard-library one (zlib), so no imaging
package is needed.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Sequence
from pathlib import Path

import numpy as np

#: Texture kinds :func:`make_texture` knows.
KINDS = ("noise", "wood", "checker", "stripes", "plaster")


def write_png(path: Path, rgb: np.ndarray) -> None:
    """Writes an 8-bit RGB image (H x W x 3, uint8) as PNG."""
    if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"write_png wants H x W x 3 uint8, got {rgb.shape} {rgb.dtype}")
    h, w, _ = rgb.shape
    raw = b"".join(b"\x00" + rgb[y].tobytes() for y in range(h))

    def chunk(tag: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)

    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
    png += chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b"")
    Path(path).write_bytes(png)


def _value_noise(rng: np.random.Generator, size: int, octaves: int = 5, base_cells: int = 4) -> np.ndarray:
    """Fractal value noise in [0, 1], tileable (periodic grid), size x size; the coarsest
    octave has `base_cells` cells across."""
    out = np.zeros((size, size))
    amp, total = 1.0, 0.0
    for o in range(octaves):
        cells = min(base_cells * 2**o, size)
        grid = rng.random((cells, cells))
        t = np.arange(size) * cells / size
        i0 = np.floor(t).astype(int)
        f = t - i0
        f = f * f * (3 - 2 * f)
        i1 = (i0 + 1) % cells
        gy0, gy1 = grid[i0], grid[i1]
        rows = gy0 * (1 - f)[:, None] + gy1 * f[:, None]
        layer = rows[:, i0] * (1 - f)[None, :] + rows[:, i1] * f[None, :]
        out += amp * layer
        total += amp
        amp *= 0.55
    return out / total


def make_texture(rng: np.random.Generator, kind: str, base_rgb: Sequence[float],
                 size: int = 256, scale: int = 1) -> np.ndarray:
    """A size x size x 3 uint8 texture of `kind` around the colour `base_rgb` (0..1);
    `scale` > 1 repeats the pattern's features that many times more densely (for large
    surfaces such as the floor and walls)."""
    base = np.asarray(base_rgb, dtype=float)
    n = _value_noise(rng, size, base_cells=4 * scale)
    yy, xx = np.mgrid[0:size, 0:size] / size
    if kind == "noise":
        shade = 0.55 + 0.9 * (n - 0.5) * 1.6
    elif kind == "plaster":
        fine = _value_noise(rng, size, octaves=6, base_cells=8 * scale)
        shade = 0.78 + 0.9 * (fine - 0.5) + 0.3 * (n - 0.5)
    elif kind == "wood":
        freq = rng.uniform(8, 16) * scale
        rings = np.sin(2 * np.pi * (freq * yy + 3.0 * n))
        shade = 0.75 + 0.18 * rings + 0.25 * (n - 0.5)
    elif kind == "checker":
        cells = int(rng.integers(4, 9)) * scale
        check = ((np.floor(xx * cells) + np.floor(yy * cells)) % 2) * 2 - 1
        shade = 0.75 + 0.2 * check + 0.3 * (n - 0.5)
    elif kind == "stripes":
        freq = int(rng.integers(3, 9)) * scale
        angle = rng.uniform(0, np.pi)
        s = np.sin(2 * np.pi * freq * (np.cos(angle) * xx + np.sin(angle) * yy))
        shade = 0.7 + 0.25 * np.sign(s) * np.abs(s) ** 0.3 + 0.3 * (n - 0.5)
    else:
        raise ValueError(f"unknown texture kind {kind!r}; known: {', '.join(KINDS)}")
    img = np.clip(shade[..., None] * base[None, None, :], 0.0, 1.0)
    out: np.ndarray = (img * 255.0 + 0.5).astype(np.uint8)
    return out
