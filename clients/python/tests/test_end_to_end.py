"""Training and serving share one preprocessing: Rust ``vamos export-dataset`` writes the
dataset, ``vamos-train`` fits and exports a bundle from it, and the Rust server's loader
(``vamos model inspect``) accepts the bundle.

Needs the ``vamos`` binary: ``VAMOS_BIN`` names it (``scripts/test.sh`` sets it after
``cargo test --release`` built it). Without ``VAMOS_BIN`` the test is skipped; with a
``VAMOS_BIN`` that does not exist it fails.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from vamos.bundle import read_bundle


def _vamos_bin() -> Path:
    value = os.environ.get("VAMOS_BIN")
    if not value:
        pytest.skip("VAMOS_BIN is not set (scripts/test.sh sets it)")
    path = Path(value)
    assert path.is_file(), f"VAMOS_BIN={value} does not exist"
    return path


def _texture(seed: int, h: int, w: int, dx: float, dy: float, k: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    x = x - dx * k
    y = y - dy * k
    img = np.zeros((h, w))
    for _ in range(24):
        wl = rng.uniform(6, 40)
        ang = rng.uniform(0, 2 * np.pi)
        ph = rng.uniform(0, 2 * np.pi)
        img += np.cos(2 * np.pi / wl * (np.cos(ang) * x + np.sin(ang) * y) + ph)
    img = (img - img.min()) / (img.max() - img.min())
    return (20 + 215 * img).astype(np.uint8)


def _write_png(path: Path, img: np.ndarray) -> None:
    import zlib
    import struct

    h, w = img.shape
    raw = b"".join(b"\x00" + img[r].tobytes() for r in range(h))

    def chunk(tag: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)

    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0))
    png += chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")
    path.write_bytes(png)


def test_export_train_and_load_in_rust(tmp_path: Path) -> None:
    vamos = _vamos_bin()
    episodes = []
    for e in range(3):
        d = tmp_path / f"ep{e}"
        d.mkdir()
        for k in range(8):
            _write_png(d / f"{k:03d}.png", _texture(e, 60, 80, 0.5 + 0.2 * e, -0.3, k))
        episodes.append(str(d))
    env = dict(os.environ, VAMOS_PIPELINE__FRAMES__WIDTH="80", VAMOS_PIPELINE__FRAMES__HEIGHT="60")
    env.pop("VAMOS_CONFIG", None)
    ds = tmp_path / "dataset"
    out = subprocess.run([str(vamos), "export-dataset", *episodes, "-o", str(ds), "--preset", "realtime"],
                         capture_output=True, text=True, env=env, timeout=300)
    assert out.returncode == 0, out.stderr
    manifest = json.loads((ds / "manifest.json").read_text())
    assert [len(e["frames"]) for e in manifest["episodes"]] == [7, 7, 7]
    rows = np.load(ds / "ep0.npy")
    assert rows.shape == (7, 2, 64, 64) and rows.dtype == np.float32
    # 0.5 px per frame at 80 px wide = 4 px at 640 -> 4 / 15 * 0.5 = 0.133.
    assert abs(float(rows[:, 0].mean()) - 0.1333) < 0.03

    run = tmp_path / "run"
    import vamos as package

    train_env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONPATH=str(Path(package.__file__).parent.parent))
    fit = subprocess.run([sys.executable, "-m", "vamos.train", "fit", str(ds), "-o", str(run),
                          "--filters", "4,8,8,8", "--epochs", "1", "--batch-size", "4", "--a", "2", "--b", "1",
                          "--val-episodes", "ep2", "--threads", "1", "--no-progress", "--seed", "1"],
                         capture_output=True, text=True, env=train_env, timeout=600)
    assert fit.returncode == 0, fit.stderr
    bundle = read_bundle(run / "model.vamos")
    assert bundle.manifest["temporal"]["a"] == 2
    assert bundle.manifest["processing"] == {"width": 80, "height": 60, "stride": 1}

    inspect = subprocess.run([str(vamos), "model", "inspect", str(run / "model.vamos")],
                             capture_output=True, text=True, env=env, timeout=300)
    assert inspect.returncode == 0, inspect.stderr
    report = json.loads(inspect.stdout)
    # The U-Net ends with filters[0] channels.
    assert report["dims"] == {"channels": 4, "latent": 6, "size": 64}
    assert report["valid"] is True
