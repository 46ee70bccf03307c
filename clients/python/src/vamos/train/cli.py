"""The ``vamos-train`` command.

Sub-commands::

    vamos-train fit DATASET_DIR -o RUN_DIR [options]   train, checkpoint, export RUN_DIR/model.vamos
    vamos-train export CHECKPOINT -o MODEL.vamos        export a checkpoint
    vamos-train export-random -o MODEL.vamos [--filters ...]   export an untrained network
    vamos-train bench-step [--filters ...]              time training steps

``vamos-train DATASET_DIR -o RUN_DIR`` (no sub-command) means ``fit``, and
``vamos-train --export-only CHECKPOINT -o MODEL.vamos`` means ``export``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence

from vamos._cli import add_version
from vamos.train.config import PAPER_FILTERS, ConfigError, FitConfig, ModelConfig, parse_filters

_SUBCOMMANDS = ("fit", "export", "export-random", "bench-step")


def _filters(text: str) -> tuple[int, ...]:
    try:
        return parse_filters(text)
    except ConfigError as err:
        raise argparse.ArgumentTypeError(str(err)) from err


def _names(text: str) -> list[str]:
    return [part for part in text.split(",") if part]


def _add_model_args(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("network")
    g.add_argument("--filters", type=_filters, default=PAPER_FILTERS,
                   help="filters per U-Net level, comma-separated (default: 32,64,128,192)")
    g.add_argument("--width", type=float, default=None,
                   help="width multiplier applied to --filters (e.g. 0.5 gives 16,32,64,96)")
    g.add_argument("--latent", type=int, default=6, help="latent dimension (default 6)")
    g.add_argument("--fcomb-channels", type=int, default=None,
                   help="fcomb hidden width (default: first filter count)")


def _model_config(args: argparse.Namespace, input_size: int = 64) -> ModelConfig:
    filters = tuple(args.filters)
    if args.width is not None:
        filters = tuple(max(1, round(f * args.width)) for f in filters)
    return ModelConfig(filters=filters, latent_dim=args.latent, fcomb_channels=args.fcomb_channels,
                       input_size=input_size)


def _add_runtime_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--device", default="auto", help="auto (cuda if available, else cpu), cpu, cuda, cuda:N")
    p.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's choice)")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser (sub-commands fit, export, export-random, bench-step)."""
    parser = argparse.ArgumentParser(prog="vamos-train", description=(__doc__ or "").replace("``", ""),
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    add_version(parser)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    fit = sub.add_parser("fit", help="train on a dataset and export RUN_DIR/model.vamos")
    fit.add_argument("dataset", help="dataset directory (manifest.json + <episode>.npy)")
    fit.add_argument("-o", "--output", required=True, help="run folder (checkpoints, logs, model.vamos)")
    _add_model_args(fit)
    g = fit.add_argument_group("training")
    g.add_argument("--epochs", type=int, default=50, help="epochs (default %(default)s)")
    g.add_argument("--batch-size", type=int, default=128, help="pairs per step (default %(default)s)")
    g.add_argument("--lr", type=float, default=1e-4, help="Adam learning rate")
    g.add_argument("--beta", type=float, default=10.0, help="weight of KL(posterior || prior)")
    g.add_argument("--free-bits", type=float, default=0.0,
                   help="free bits, nats per latent dimension: the loss uses max(KL of the dimension, "
                        "this) per dimension, against posterior collapse (default 0: off; e.g. 0.1)")
    g.add_argument("--kl-warmup-epochs", type=int, default=0,
                   help="KL annealing: the KL weight ramps linearly from 0 to --beta over this many "
                        "epochs (default 0: off)")
    g.add_argument("--weight-decay", type=float, default=1e-5,
                   help="coefficient of the prior/posterior/fcomb weight-norm term")
    g.add_argument("--a", type=int, default=5, help="smallest past offset A (flow frames)")
    g.add_argument("--b", type=int, default=4, help="offset range B: n uniform in {A..A+B}")
    g.add_argument("--m", type=int, default=10, help="prior samples per offset at inference (manifest)")
    g.add_argument("--val-fraction", type=float, default=0.1, help="fraction of episodes for validation")
    g.add_argument("--val-episodes", type=_names, default=None, help="explicit validation episodes, comma-separated")
    g.add_argument("--train-episodes", type=_names, default=None, help="explicit training episodes, comma-separated")
    g.add_argument("--seed", type=int, default=0, help="seed of weights, split and sampling (default 0)")
    g.add_argument("--name", default=None, help="model name in the manifest (default: run folder name)")
    g.add_argument("--keep-every", type=int, default=0, help="keep a checkpoint copy every K epochs")
    g.add_argument("--resume", action="store_true", help="continue from RUN_DIR/checkpoints/last.pt")
    g.add_argument("--no-progress", action="store_true", help="no progress bars")
    g.add_argument("--channels-last", action=argparse.BooleanOptionalAction, default=None,
                   help="NHWC activations (default: on for CPU, off for CUDA)")
    _add_runtime_args(fit)

    export = sub.add_parser("export", help="export a checkpoint to a model bundle")
    export.add_argument("checkpoint", help="checkpoint file (RUN_DIR/checkpoints/last.pt)")
    export.add_argument("-o", "--output", required=True, help="bundle path (*.vamos)")
    export.add_argument("--name", default=None, help="model name (default: the run's)")
    export.add_argument("--no-verify", action="store_true", help="skip the onnxruntime parity check")

    rand = sub.add_parser("export-random", help="export an untrained network (benchmarks, tests)")
    rand.add_argument("-o", "--output", required=True, help="bundle path (*.vamos)")
    _add_model_args(rand)
    rand.add_argument("--seed", type=int, default=0, help="weight initialisation seed")
    rand.add_argument("--name", default=None, help="model name (default: untrained-<filters>)")
    rand.add_argument("--size", type=int, default=64, help="input size S")
    rand.add_argument("--clip-px", type=float, default=15.0,
                      help="flow magnitude mapped to +-0.5 at the reference width, px (default %(default)s)")
    rand.add_argument("--reference-width-px", type=int, default=640,
                      help="image width --clip-px refers to, px (default %(default)s)")
    rand.add_argument("--flow-variant", default="plain",
                      choices=["plain", "registered", "masked", "masked_registered"],
                      help="the flow the network takes, recorded in the manifest (default %(default)s)")
    rand.add_argument("--proc-width", type=int, default=640, help="processing width, px")
    rand.add_argument("--proc-height", type=int, default=480, help="processing height, px")
    rand.add_argument("--stride", type=int, default=1, help="processing stride")
    rand.add_argument("--a", type=int, default=5, help="smallest past offset A (flow frames)")
    rand.add_argument("--b", type=int, default=4, help="offset range B: n in {A..A+B}")
    rand.add_argument("--m", type=int, default=10, help="prior samples per offset at inference (manifest)")
    rand.add_argument("--no-verify", action="store_true", help="skip the onnxruntime parity check")

    bench = sub.add_parser("bench-step", help="time training steps (forward + backward + Adam)")
    _add_model_args(bench)
    bench.add_argument("--batch-size", type=int, default=128, help="pairs per step (default %(default)s)")
    bench.add_argument("--steps", type=int, default=3, help="timed steps (default %(default)s)")
    bench.add_argument("--warmup", type=int, default=1, help="untimed steps first (default %(default)s)")
    bench.add_argument("--channels-last", action=argparse.BooleanOptionalAction, default=None,
                       help="NHWC activations (default: on for CPU, off for CUDA)")
    _add_runtime_args(bench)
    return parser


def _normalise_argv(argv: list[str]) -> list[str]:
    if argv and argv[0] == "--export-only":
        return ["export", *argv[1:]]
    if argv and argv[0] not in _SUBCOMMANDS and argv[0] not in ("-h", "--help", "--version"):
        return ["fit", *argv]
    return argv


def _print_diffs(diffs: dict[str, float] | None) -> None:
    if diffs is not None:
        print("onnxruntime vs torch max abs diff: " + ", ".join(f"{k} {v:.2g}" for k, v in diffs.items()))


def _cmd_fit(args: argparse.Namespace) -> int:
    from vamos.train.data import load_dataset

    cfg = FitConfig(
        dataset_dir=args.dataset, run_dir=args.output, model=_model_config(args),
        epochs=args.epochs, batch_size=args.batch_size, learning_rate=args.lr, beta=args.beta,
        free_bits=args.free_bits, kl_warmup_epochs=args.kl_warmup_epochs,
        weight_decay=args.weight_decay, a=args.a, b=args.b, m=args.m, val_fraction=args.val_fraction,
        val_episodes=args.val_episodes, train_episodes=args.train_episodes, seed=args.seed,
        device=args.device, threads=args.threads, name=args.name, keep_every=args.keep_every,
        progress=not args.no_progress, channels_last=args.channels_last,
    )
    cfg.validate()  # fail fast on bad settings and a bad dataset, before importing torch
    load_dataset(args.dataset)
    from vamos.train.trainer import fit

    result = fit(cfg, resume=args.resume)
    print(f"wrote {result.bundle}")
    return 0


def _cmd_export(args: argparse.Namespace) -> int:
    from vamos.train.trainer import export_checkpoint

    manifest, diffs = export_checkpoint(args.checkpoint, args.output, name=args.name, verify=not args.no_verify)
    print(f"wrote {args.output} ({manifest['architecture']['parameters_inference']} inference parameters)")
    _print_diffs(diffs)
    return 0


def _cmd_export_random(args: argparse.Namespace) -> int:
    import torch

    from vamos.train.export import BundleInfo, export_bundle, verify_bundle
    from vamos.train.model import ProbabilisticUNet

    config = _model_config(args, input_size=args.size)
    torch.manual_seed(args.seed)
    model = ProbabilisticUNet(config)
    info = BundleInfo(
        name=args.name or "untrained-" + "-".join(str(f) for f in config.filters),
        clip_px=args.clip_px, reference_width_px=args.reference_width_px, flow_variant=args.flow_variant,
        processing={"width": args.proc_width, "height": args.proc_height, "stride": args.stride},
        temporal={"a": args.a, "b": args.b, "m": args.m},
        training={
            "episodes_train": 0, "episodes_validation": 0, "frames_train": 0, "epochs": 0,
            "batch_size": 0, "learning_rate": 0.0, "beta": 0.0, "weight_decay": 0.0, "seed": args.seed,
            "final_train_loss": None, "final_validation_loss": None,
            "dataset": f"untrained: random initialisation (torch.manual_seed({args.seed}))",
        },
    )
    manifest = export_bundle(model, args.output, info, verify=False)
    print(f"wrote {args.output} ({json.dumps(manifest['architecture'])})")
    _print_diffs(None if args.no_verify else verify_bundle(args.output, model))
    return 0


def _cmd_bench_step(args: argparse.Namespace) -> int:
    import torch

    from vamos.train.losses import training_loss
    from vamos.train.model import ProbabilisticUNet, parameter_counts
    from vamos.train.trainer import resolve_device

    if args.threads is not None:
        torch.set_num_threads(args.threads)
    device = resolve_device(args.device)
    torch.manual_seed(0)
    config = _model_config(args)
    model = ProbabilisticUNet(config).to(device)
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-4)
    shape = (args.batch_size, 2, config.input_size, config.input_size)
    past = (torch.rand(shape) - 0.5).to(device)
    target = (torch.rand(shape) - 0.5).to(device)
    eps = torch.randn(args.batch_size, config.latent_dim).to(device)
    channels_last = args.channels_last if args.channels_last is not None else device.type == "cpu"
    if channels_last:
        model.to(memory_format=torch.channels_last)
        past = past.contiguous(memory_format=torch.channels_last)
        target = target.contiguous(memory_format=torch.channels_last)
    times = []
    for step in range(args.warmup + args.steps):
        if device.type == "cuda":
            torch.cuda.synchronize()
        started = time.perf_counter()
        terms = training_loss(model, past, target, eps, 10.0, 1e-5)
        optimizer.zero_grad(set_to_none=True)
        terms.total.backward()
        optimizer.step()
        if device.type == "cuda":
            torch.cuda.synchronize()
        if step >= args.warmup:
            times.append(time.perf_counter() - started)
    counts = parameter_counts(model)
    print(json.dumps({
        "filters": list(config.filters), "batch_size": args.batch_size, "device": str(device),
        "threads": torch.get_num_threads(), "channels_last": channels_last, "parameters": counts,
        "step_seconds_min": min(times), "step_seconds_mean": sum(times) / len(times), "steps": len(times),
    }))
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``vamos-train``; returns the exit status."""
    args = build_parser().parse_args(_normalise_argv(list(sys.argv[1:] if argv is None else argv)))
    handlers = {"fit": _cmd_fit, "export": _cmd_export, "export-random": _cmd_export_random,
                "bench-step": _cmd_bench_step}
    from vamos.bundle import BundleError
    from vamos.train.data import DatasetError

    try:
        return handlers[args.command](args)
    except (ConfigError, DatasetError, BundleError, FileNotFoundError) as err:
        print(f"vamos-train: error: {err}", file=sys.stderr)
        return 2
    except ValueError as err:  # CheckpointError, ExportError and friends
        print(f"vamos-train: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
