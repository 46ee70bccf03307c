"""Training loop: logs, checkpoints, resume equivalence."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from conftest import tiny_fit_config
from vamos.train.trainer import CheckpointError, fit, load_checkpoint


def test_resume_equals_uninterrupted_run(tiny_dataset: Path, tmp_path: Path) -> None:
    straight = fit(tiny_fit_config(tiny_dataset, tmp_path / "straight", epochs=2), export=False)
    fit(tiny_fit_config(tiny_dataset, tmp_path / "resumed", epochs=1), export=False)
    first = load_checkpoint(tmp_path / "resumed" / "checkpoints" / "last.pt")
    assert first["epoch"] == 1
    resumed = fit(tiny_fit_config(tiny_dataset, tmp_path / "resumed", epochs=2), resume=True, export=False)

    a = load_checkpoint(tmp_path / "straight" / "checkpoints" / "last.pt")
    b = load_checkpoint(tmp_path / "resumed" / "checkpoints" / "last.pt")
    assert a["epoch"] == b["epoch"] == 2
    for key, value in a["model_state"].items():
        assert torch.equal(value, b["model_state"][key]), key
    # Training did move the weights.
    assert any(not torch.equal(v, first["model_state"][k]) for k, v in a["model_state"].items())
    def losses(history: list[dict]) -> list[tuple]:
        return [(r["epoch"], r["train"], r["validation"]) for r in history]

    assert losses(straight.history) == losses(resumed.history)
    for key in ("exp_avg", "exp_avg_sq"):
        for i, state in a["optimizer_state"]["state"].items():
            assert torch.equal(state[key], b["optimizer_state"]["state"][i][key])


def test_run_folder_contents(tiny_dataset: Path, tmp_path: Path) -> None:
    cfg = tiny_fit_config(tiny_dataset, tmp_path / "run", epochs=2)
    cfg.keep_every = 1
    result = fit(cfg, export=False)
    run = tmp_path / "run"
    lines = [json.loads(line) for line in (run / "log.jsonl").read_text().splitlines()]
    assert [r["epoch"] for r in lines] == [1, 2]
    for record in lines:
        for part in ("train", "validation"):
            losses = record[part]
            assert set(losses) == {"total", "mse", "kl", "reg", "samples"}
            assert abs(losses["total"] - (losses["mse"] + 10.0 * losses["kl"] + 1e-5 * losses["reg"])) < 1e-5
    # 5 episodes, val fraction 0.2: 1 held out; 5 valid targets per episode.
    assert lines[0]["train"]["samples"] == 20 and lines[0]["validation"]["samples"] == 5
    config = json.loads((run / "config.json").read_text())
    assert len(config["split"]["train"]) == 4 and len(config["split"]["validation"]) == 1
    assert set(config["split"]["train"]).isdisjoint(config["split"]["validation"])
    assert (run / "checkpoints" / "epoch_0001.pt").exists() and (run / "checkpoints" / "epoch_0002.pt").exists()
    ckpt = load_checkpoint(run / "checkpoints" / "last.pt")
    assert set(ckpt["rng"]) == {"python", "numpy", "torch", "cuda"}
    assert ckpt["history"] == result.history == lines


def test_resume_without_checkpoint_is_an_error(tiny_dataset: Path, tmp_path: Path) -> None:
    with pytest.raises(CheckpointError, match="no checkpoint"):
        fit(tiny_fit_config(tiny_dataset, tmp_path / "none", epochs=1), resume=True)


def test_channels_last_trains_like_contiguous(tiny_dataset: Path, tmp_path: Path) -> None:
    """NHWC activations only change the memory layout: same weights to float rounding."""
    nchw = tiny_fit_config(tiny_dataset, tmp_path / "nchw", epochs=1)
    nchw.channels_last = False
    fit(nchw, export=False)
    cfg = tiny_fit_config(tiny_dataset, tmp_path / "nhwc", epochs=1)
    cfg.channels_last = True
    fit(cfg, export=False)
    a = load_checkpoint(tmp_path / "nchw" / "checkpoints" / "last.pt")["model_state"]
    b = load_checkpoint(tmp_path / "nhwc" / "checkpoints" / "last.pt")["model_state"]
    for key, value in a.items():
        assert b[key].is_contiguous()
        assert torch.allclose(value, b[key], atol=1e-5), key
