"""The training loop: seeding, epochs, logs, checkpoints, resume, final export.

A run folder holds::

    config.json            the effective configuration
    log.jsonl              one JSON object per epoch (train/validation total, mse, kl, reg; beta)
    checkpoints/last.pt    model, optimiser, RNG states, epoch, history (every epoch),
                           after the last epoch also the collapse check
    checkpoints/epoch_NNNN.pt  copies every ``keep_every`` epochs (if asked)
    model.vamos            the exported bundle (after the last epoch); its manifest's
                           ``training`` object (the run's summary) has the collapse check

After the last epoch :func:`vamos.train.collapse.collapse_check` measures KL and the
spread of the prior's samples on the validation pairs (the training pairs without a
validation split), prints them and warns when the posterior has collapsed.

Reproducibility: weights are initialised from ``seed``; epoch ``e``'s sample order and
offsets come from ``numpy.random.default_rng([seed, e, 1])`` and its latent noise from a
torch CPU generator seeded from the same sequence, so an epoch's randomness depends only
on ``(seed, e)``. Resuming from ``last.pt`` therefore continues exactly like an
uninterrupted run (bit-identical on CPU with the same thread count). Global python, numpy
and torch RNG states are seeded too and saved in checkpoints.
"""

from __future__ import annotations

import json
import math
import os
import random
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from vamos.train.collapse import collapse_check, collapse_summary, collapse_warning
from vamos.train.config import ConfigError, FitConfig, ModelConfig
from vamos.train.data import PairSampler, load_dataset, split_episodes
from vamos.train.export import BundleInfo, export_bundle, verify_bundle
from vamos.train.losses import training_loss
from vamos.train.model import ProbabilisticUNet, parameter_counts

#: ``format`` field of a training checkpoint.
CHECKPOINT_FORMAT = "vamos-train-checkpoint"
#: Checkpoint layout version.
CHECKPOINT_VERSION = 1


class CheckpointError(ValueError):
    """A checkpoint cannot be used (missing, wrong format, incompatible with the run)."""

    def __init__(self, path: str | Path, reason: str) -> None:
        self.path = str(path)
        self.reason = reason
        super().__init__(f"{self.path}: {reason}")


def resolve_device(spec: str) -> torch.device:
    """``"auto"`` -> cuda if available else cpu; anything else is passed to torch."""
    if spec == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        return torch.device(spec)
    except RuntimeError as err:
        raise ConfigError("device", str(err)) from err


def seed_everything(seed: int) -> None:
    """Seed python's ``random``, numpy's global RNG and torch (CPU and CUDA)."""
    random.seed(seed)
    np.random.seed(seed % 2**32)
    torch.manual_seed(seed)


def _rng_states() -> dict[str, Any]:
    kind, keys, pos, has_gauss, cached = np.random.get_state()
    return {
        "python": random.getstate(),
        "numpy": {"kind": kind, "keys": [int(k) for k in keys], "pos": int(pos),
                  "has_gauss": int(has_gauss), "cached_gaussian": float(cached)},
        "torch": torch.get_rng_state(),
        "cuda": torch.cuda.get_rng_state_all() if torch.cuda.is_available() else [],
    }


def _restore_rng_states(states: dict[str, Any]) -> None:
    python = states["python"]
    random.setstate((python[0], tuple(python[1]), python[2]))
    n = states["numpy"]
    keys = np.array(n["keys"], dtype=np.uint32)
    np.random.set_state((n["kind"], keys, n["pos"], n["has_gauss"], n["cached_gaussian"]))
    torch.set_rng_state(states["torch"])
    if states["cuda"] and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(states["cuda"])


def _epoch_rngs(seed: int, epoch: int, stream: int) -> tuple[np.random.Generator, torch.Generator]:
    rng = np.random.default_rng([seed, epoch, stream])
    generator = torch.Generator().manual_seed(int(rng.integers(0, 2**62)))
    return rng, generator


@dataclass
class EpochLosses:
    """Sample-weighted means of the loss pieces over an epoch."""

    total: float
    mse: float
    kl: float
    reg: float
    samples: int


def run_epoch(
    model: ProbabilisticUNet,
    sampler: PairSampler,
    rng: np.random.Generator,
    generator: torch.Generator,
    batch_size: int,
    beta: float,
    weight_decay: float,
    device: torch.device,
    optimizer: torch.optim.Optimizer | None,
    desc: str = "",
    progress: bool = False,
    channels_last: bool = False,
    free_bits: float = 0.0,
) -> EpochLosses:
    """One pass over the sampler's plan; trains if ``optimizer`` is given, else evaluates.

    ``total`` is the loss optimised (with ``free_bits``' floored KL term); ``kl`` the true KL.

    Training shuffles and draws ``z`` from the posterior with noise from ``generator``;
    evaluation keeps the target order (``n`` still drawn from ``rng``).
    """
    train = optimizer is not None
    model.train(train)
    plan = sampler.plan(rng, shuffle=train)
    sums = {"total": 0.0, "mse": 0.0, "kl": 0.0, "reg": 0.0}
    batches = range(0, len(plan), batch_size)
    bar = tqdm(batches, desc=desc, leave=False, disable=not progress, unit="batch")
    with torch.set_grad_enabled(train):
        for start in bar:
            past_np, target_np = sampler.gather(plan, start, start + batch_size)
            past = torch.from_numpy(past_np).to(device)
            target = torch.from_numpy(target_np).to(device)
            if channels_last:
                past = past.contiguous(memory_format=torch.channels_last)
                target = target.contiguous(memory_format=torch.channels_last)
            eps = torch.randn(past.shape[0], model.config.latent_dim, generator=generator).to(device)
            terms = training_loss(model, past, target, eps, beta, weight_decay, free_bits)
            if optimizer is not None:
                optimizer.zero_grad(set_to_none=True)
                terms.total.backward()
                optimizer.step()
            count = past.shape[0]
            for key in sums:
                sums[key] += float(getattr(terms, key).detach()) * count
            bar.set_postfix(loss=f"{float(terms.total.detach()):.4g}")
    total = len(plan)
    if total == 0:
        nan = float("nan")
        return EpochLosses(nan, nan, nan, nan, 0)
    return EpochLosses(**{k: v / total for k, v in sums.items()}, samples=total)


def _fit_dict(cfg: FitConfig) -> dict[str, Any]:
    out = asdict(cfg)
    out["model"] = cfg.model.to_dict()
    return out


def _fit_from_dict(data: dict[str, Any]) -> FitConfig:
    data = dict(data)
    data["model"] = ModelConfig.from_dict(data["model"])
    return FitConfig(**data)


def _atomic_torch_save(obj: Any, path: Path) -> None:
    tmp = path.with_name(path.name + ".tmp")
    torch.save(obj, tmp)
    os.replace(tmp, path)


def load_checkpoint(path: str | Path) -> dict[str, Any]:
    """Load a checkpoint (CPU tensors, ``weights_only``) and check its format."""
    path = Path(path)
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except (OSError, RuntimeError, EOFError) as err:
        raise CheckpointError(path, f"cannot load ({err})") from err
    if not isinstance(ckpt, dict) or ckpt.get("format") != CHECKPOINT_FORMAT:
        raise CheckpointError(path, f"not a {CHECKPOINT_FORMAT}")
    if ckpt.get("version") != CHECKPOINT_VERSION:
        raise CheckpointError(path, f"checkpoint version {ckpt.get('version')!r}, expected {CHECKPOINT_VERSION}")
    return ckpt


def model_from_checkpoint(ckpt: dict[str, Any]) -> ProbabilisticUNet:
    """The network stored in a checkpoint (CPU)."""
    model = ProbabilisticUNet(ModelConfig.from_dict(ckpt["fit"]["model"]))
    model.load_state_dict(ckpt["model_state"])
    return model


def bundle_info_from_checkpoint(ckpt: dict[str, Any], name: str | None = None) -> BundleInfo:
    """Manifest fields of a checkpoint's run (dataset settings and training summary)."""
    fit = ckpt["fit"]
    ds = ckpt["dataset"]
    history = ckpt["history"]
    last = history[-1] if history else None

    def final(part: str) -> float | None:
        if last is None or last.get(part) is None:
            return None
        value = last[part]["total"]
        return None if value is None or math.isnan(value) else float(value)

    return BundleInfo(
        name=name or fit["name"] or Path(fit["run_dir"]).name,
        clip_px=float(ds["input"]["clip_px"]),
        reference_width_px=int(ds["input"]["reference_width_px"]),
        flow_variant=str(ds["flow_variant"]),
        processing={k: int(ds["processing"][k]) for k in ("width", "height", "stride")},
        temporal={"a": fit["a"], "b": fit["b"], "m": fit["m"]},
        training={
            "episodes_train": len(ckpt["split"]["train"]),
            "episodes_validation": len(ckpt["split"]["validation"]),
            "frames_train": int(ds["frames_train"]),
            "epochs": int(ckpt["epoch"]),
            "batch_size": fit["batch_size"],
            "learning_rate": fit["learning_rate"],
            "beta": fit["beta"],
            "free_bits": fit.get("free_bits", 0.0),
            "kl_warmup_epochs": fit.get("kl_warmup_epochs", 0),
            "weight_decay": fit["weight_decay"],
            "seed": fit["seed"],
            "final_train_loss": final("train"),
            "final_validation_loss": final("validation"),
            "dataset": str(ds["path"]),
            **({"collapse_check": ckpt["collapse_check"]} if ckpt.get("collapse_check") is not None else {}),
        },
    )


def export_checkpoint(
    checkpoint: str | Path, out: str | Path, name: str | None = None, verify: bool = True
) -> tuple[dict[str, Any], dict[str, float] | None]:
    """Export a checkpoint's model to a bundle.

    Returns the manifest and, with ``verify``, the max abs difference per output between
    onnxruntime and torch (:func:`vamos.train.export.verify_bundle`; raises above 1e-4).
    """
    ckpt = load_checkpoint(checkpoint)
    model = model_from_checkpoint(ckpt)
    manifest = export_bundle(model, out, bundle_info_from_checkpoint(ckpt, name), verify=False)
    return manifest, verify_bundle(out, model) if verify else None


@dataclass
class FitResult:
    """Outcome of :func:`fit`."""

    #: Path of the exported bundle.
    bundle: Path
    #: Per-epoch log records (as in ``log.jsonl``).
    history: list[dict[str, Any]]
    #: The bundle manifest.
    manifest: dict[str, Any]
    #: The trained model (on the training device).
    model: ProbabilisticUNet
    #: The collapse check after the last epoch (:meth:`vamos.train.collapse.CollapseCheck.to_dict`).
    collapse: dict[str, Any] | None = None


def _losses_record(losses: EpochLosses) -> dict[str, Any] | None:
    if losses.samples == 0:
        return None
    return asdict(losses)


def fit(cfg: FitConfig, resume: bool = False, export: bool = True) -> FitResult:
    """Train per ``cfg``, checkpoint every epoch, then export ``run_dir/model.vamos``.

    With ``resume``, ``run_dir/checkpoints/last.pt`` supplies the configuration (except
    ``epochs``, ``device``, ``threads``, ``channels_last``, ``progress``, ``keep_every``,
    ``dataset_dir``),
    weights, optimiser and RNG states, and training continues to ``cfg.epochs``.
    """
    run_dir = Path(cfg.run_dir)
    last_path = run_dir / "checkpoints" / "last.pt"
    ckpt: dict[str, Any] | None = None
    if resume:
        if not last_path.exists():
            raise CheckpointError(last_path, "no checkpoint to resume from")
        ckpt = load_checkpoint(last_path)
        saved = _fit_from_dict(ckpt["fit"])
        for key in ("epochs", "device", "threads", "progress", "keep_every", "dataset_dir", "run_dir",
                "channels_last"):
            setattr(saved, key, getattr(cfg, key))
        cfg = saved
    cfg.validate()
    if cfg.threads is not None:
        torch.set_num_threads(cfg.threads)
    device = resolve_device(cfg.device)
    channels_last = cfg.channels_last if cfg.channels_last is not None else device.type == "cpu"

    dataset = load_dataset(cfg.dataset_dir)
    if dataset.input_size != cfg.model.input_size:
        cfg.model = ModelConfig.from_dict({**cfg.model.to_dict(), "input_size": dataset.input_size})
    names = [e.name for e in dataset.episodes]
    if ckpt is not None:
        train_names, val_names = list(ckpt["split"]["train"]), list(ckpt["split"]["validation"])
        missing = [n for n in train_names + val_names if n not in names]
        if missing:
            raise CheckpointError(last_path, f"episodes {missing} of the checkpoint are not in {cfg.dataset_dir}")
    else:
        train_names, val_names = split_episodes(
            names, cfg.val_fraction, cfg.seed, cfg.val_episodes, cfg.train_episodes
        )
    train_sampler = PairSampler([dataset.episode(n) for n in train_names], cfg.a, cfg.b)
    val_sampler = PairSampler([dataset.episode(n) for n in val_names], cfg.a, cfg.b)
    if len(train_sampler) == 0:
        raise ConfigError("a/b", f"no training episode is longer than a + b = {cfg.a + cfg.b} frames")

    seed_everything(cfg.seed)
    model = ProbabilisticUNet(cfg.model)
    model.to(device)
    if channels_last:
        model.to(memory_format=torch.channels_last)
    optimizer = torch.optim.Adam(model.parameters(), lr=cfg.learning_rate)
    history: list[dict[str, Any]] = []
    start_epoch = 0
    if ckpt is not None:
        model.load_state_dict(ckpt["model_state"])
        optimizer.load_state_dict(ckpt["optimizer_state"])
        _restore_rng_states(ckpt["rng"])
        history = list(ckpt["history"])
        start_epoch = int(ckpt["epoch"])

    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "checkpoints").mkdir(exist_ok=True)
    counts = parameter_counts(model)
    (run_dir / "config.json").write_text(
        json.dumps({"fit": _fit_dict(cfg), "device": str(device), "parameters": counts,
                    "split": {"train": train_names, "validation": val_names},
                    "samples_per_epoch": {"train": len(train_sampler), "validation": len(val_sampler)}},
                   indent=2) + "\n"
    )
    log_path = run_dir / "log.jsonl"
    log_path.write_text("".join(json.dumps(record) + "\n" for record in history))
    dataset_entry = {
        "path": str(dataset.path),
        "input": dataset.manifest["input"],
        "flow_variant": dataset.manifest["flow_variant"],
        "processing": dataset.manifest["processing"],
        "frames_train": len(train_sampler),
    }

    epochs = tqdm(range(start_epoch, cfg.epochs), desc="epochs", disable=not cfg.progress, unit="epoch")
    for epoch in epochs:
        started = time.perf_counter()
        beta = cfg.effective_beta(epoch + 1)
        rng, generator = _epoch_rngs(cfg.seed, epoch, 1)
        train = run_epoch(model, train_sampler, rng, generator, cfg.batch_size, beta, cfg.weight_decay,
                          device, optimizer, desc=f"train {epoch + 1}", progress=cfg.progress,
                          channels_last=channels_last, free_bits=cfg.free_bits)
        val_rng, val_generator = _epoch_rngs(cfg.seed, 0, 2)  # same draws every epoch
        val = run_epoch(model, val_sampler, val_rng, val_generator, cfg.batch_size, beta,
                        cfg.weight_decay, device, None, desc=f"val {epoch + 1}", progress=cfg.progress,
                        channels_last=channels_last, free_bits=cfg.free_bits)
        record = {"epoch": epoch + 1, "beta": beta, "train": _losses_record(train),
                  "validation": _losses_record(val), "seconds": round(time.perf_counter() - started, 3)}
        history.append(record)
        with log_path.open("a", encoding="utf-8") as log:
            log.write(json.dumps(record) + "\n")
        val_text = f"val {val.total:.5g} (mse {val.mse:.4g}, kl {val.kl:.4g})" if val.samples else "no validation"
        beta_text = f", beta {beta:.4g}" if cfg.kl_warmup_epochs else ""
        epochs.write(f"epoch {epoch + 1}/{cfg.epochs}: train {train.total:.5g} "
                     f"(mse {train.mse:.4g}, kl {train.kl:.4g}, reg {train.reg:.4g}), {val_text}{beta_text}")
        ckpt_out = {
            "format": CHECKPOINT_FORMAT,
            "version": CHECKPOINT_VERSION,
            "epoch": epoch + 1,
            "fit": _fit_dict(cfg),
            "model_state": {k: v.detach().cpu().contiguous() for k, v in model.state_dict().items()},
            "optimizer_state": optimizer.state_dict(),
            "rng": _rng_states(),
            "history": history,
            "split": {"train": train_names, "validation": val_names},
            "dataset": dataset_entry,
        }
        _atomic_torch_save(ckpt_out, last_path)
        if cfg.keep_every and (epoch + 1) % cfg.keep_every == 0:
            _atomic_torch_save(ckpt_out, run_dir / "checkpoints" / f"epoch_{epoch + 1:04d}.pt")

    collapse = _collapse_check(cfg, model, train_sampler, val_sampler, device, channels_last)
    final = load_checkpoint(last_path)
    final["collapse_check"] = collapse
    _atomic_torch_save(final, last_path)

    bundle_path = run_dir / "model.vamos"
    manifest: dict[str, Any] = {}
    if export:
        manifest, diffs = export_checkpoint(last_path, bundle_path, cfg.name)
        print(f"exported {bundle_path}; onnxruntime vs torch max abs diff: "
              + ", ".join(f"{k} {v:.2g}" for k, v in (diffs or {}).items()))
    return FitResult(bundle=bundle_path, history=history, manifest=manifest, model=model, collapse=collapse)


def _collapse_check(cfg: FitConfig, model: ProbabilisticUNet, train_sampler: PairSampler,
                    val_sampler: PairSampler, device: torch.device, channels_last: bool) -> dict[str, Any]:
    """Run the collapse check on the validation pairs (else the training pairs), print the
    numbers (stdout) and a warning when collapsed (stderr); the check as a plain dict."""
    split, sampler = ("validation", val_sampler) if len(val_sampler) else ("train", train_sampler)
    rng, generator = _epoch_rngs(cfg.seed, 0, 2)  # the validation's pairs: its kl is the last epoch's
    check = collapse_check(model, sampler, rng, generator, max(cfg.m, 2), cfg.batch_size, device, split,
                           channels_last=channels_last)
    print(collapse_summary(check))
    warning = collapse_warning(check)
    if warning is not None:
        print(warning, file=sys.stderr)
    return check.to_dict()
