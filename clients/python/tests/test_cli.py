"""``vamos-train`` end to end in a subprocess on a tiny dataset."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from vamos.bundle import read_bundle


def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    import vamos

    env = dict(os.environ, PYTHONPATH=str(Path(vamos.__file__).parent.parent), OMP_NUM_THREADS="1")
    return subprocess.run([sys.executable, "-m", "vamos.train", *args], capture_output=True, text=True,
                          env=env, timeout=300)


def test_fit_export_and_export_random(tiny_dataset: Path, tmp_path: Path) -> None:
    run = tmp_path / "run"
    out = run_cli(str(tiny_dataset), "-o", str(run), "--filters", "4,8,8,8", "--latent", "3",
                  "--epochs", "2", "--batch-size", "16", "--lr", "1e-3", "--val-episodes", "ep0001",
                  "--seed", "3", "--threads", "1", "--no-progress", "--name", "tiny-cli")
    assert out.returncode == 0, out.stderr
    bundle = read_bundle(run / "model.vamos")
    m = bundle.manifest
    assert m["name"] == "tiny-cli"
    assert m["architecture"]["filters"] == [4, 8, 8, 8] and m["architecture"]["latent_dim"] == 3
    t = m["training"]
    assert (t["episodes_train"], t["episodes_validation"], t["frames_train"], t["epochs"]) == (4, 1, 20, 2)
    assert (t["batch_size"], t["learning_rate"], t["beta"], t["weight_decay"], t["seed"]) == (16, 1e-3, 10.0, 1e-5, 3)
    log = [json.loads(line) for line in (run / "log.jsonl").read_text().splitlines()]
    assert t["final_train_loss"] == log[-1]["train"]["total"]
    assert t["final_validation_loss"] == log[-1]["validation"]["total"]
    assert m["flow_variant"] == "plain" and m["processing"] == {"width": 640, "height": 480, "stride": 1}

    # Export of the last checkpoint reproduces the run's graphs.
    again = tmp_path / "again.vamos"
    out = run_cli("export", str(run / "checkpoints" / "last.pt"), "-o", str(again))
    assert out.returncode == 0, out.stderr
    assert read_bundle(again).manifest["members"] == m["members"]

    # Untrained network of a given width.
    rand = tmp_path / "rand.vamos"
    out = run_cli("export-random", "--filters", "8,16,16,16", "--latent", "4", "--flow-variant", "masked",
                  "--stride", "3", "-o", str(rand))
    assert out.returncode == 0, out.stderr
    r = read_bundle(rand).manifest
    assert r["architecture"]["filters"] == [8, 16, 16, 16] and r["architecture"]["latent_dim"] == 4
    assert r["flow_variant"] == "masked" and r["processing"]["stride"] == 3
    assert r["training"]["epochs"] == 0 and r["training"]["final_train_loss"] is None


def test_bad_dataset_is_a_clean_error(tmp_path: Path) -> None:
    out = run_cli("fit", str(tmp_path / "nowhere"), "-o", str(tmp_path / "run"), "--no-progress")
    assert out.returncode == 2
    assert "cannot read manifest.json" in out.stderr and "Traceback" not in out.stderr


def test_argv_shortcuts() -> None:
    from vamos.train.cli import _normalise_argv, _model_config, build_parser

    parser = build_parser()
    args = parser.parse_args(_normalise_argv(["--export-only", "ckpt.pt", "-o", "m.vamos"]))
    assert (args.command, args.checkpoint, args.output) == ("export", "ckpt.pt", "m.vamos")
    args = parser.parse_args(_normalise_argv(["data", "-o", "run", "--width", "0.5", "--latent", "4"]))
    assert (args.command, args.dataset, args.output, args.epochs, args.batch_size) == ("fit", "data", "run", 50, 128)
    assert (args.lr, args.beta, args.a, args.b, args.m, args.seed) == (1e-4, 10.0, 5, 4, 10, 0)
    config = _model_config(args)
    assert config.filters == (16, 32, 64, 96) and config.latent_dim == 4
    args = parser.parse_args(["export-random", "-o", "x.vamos", "--filters", "8,16,32,48"])
    assert _model_config(args).filters == (8, 16, 32, 48)
