"""The ``vamos-sim`` command: simulated book-to-shelf episodes as ROS 2 bags (MCAP).

::

    vamos-sim generate --out DIR --seed S --train N --val N --test-nominal N --test-anomalous N
                       [--types a,b,...] [--workers W] [--width W --height H] [--fps F] [--smoke]
                       [--robot primitive|panda] [--camera head|fixed|wrist] [--depth]

writes ``DIR/{train,val,test}/<episode>.mcap`` with ``<episode>.labels.json`` beside each,
``DIR/robot/vamos_arm.urdf`` (the robot package), ``DIR/camera.json`` (vamos's camera
description) and ``DIR/dataset.json`` (seed, counts, one entry per episode).
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from vamos._cli import add_version
from vamos.sim import robot as rb
from vamos.sim.bag import DEPTH_TOPIC
from vamos.sim.episode import (
    ANOMALY_TYPES,
    PHYSICS_HZ,
    EpisodeResult,
    EpisodeSpec,
    SimError,
    camera_spec,
    generate_episode,
)

#: Generator version, recorded in dataset.json (bump when episodes change for a seed). 2: an
#: anomaly's label ends where its objects come to rest (bags as in 1). 3: the fingers touch the
#: book they hold (the joint states read its width and the grip force, and a lost grasp), and
#: a falling, slipping or jammed book's label lasts until the shelf's books it touched are at
#: rest too.
GENERATOR_VERSION = "3"
SMOKE_COUNTS = {"train": 2, "val": 0, "test_nominal": 1, "test_anomalous": 2}
SMOKE_SIZE = (160, 120)


def _types(text: str) -> list[str]:
    names = [t for t in text.split(",") if t]
    unknown = [t for t in names if t not in ANOMALY_TYPES]
    if unknown or not names:
        raise argparse.ArgumentTypeError(f"unknown anomaly type(s) {unknown}; known: {', '.join(ANOMALY_TYPES)}")
    return names


def _count(text: str) -> int:
    n = int(text)
    if n < 0:
        raise argparse.ArgumentTypeError("counts must be >= 0")
    return n


def plan_episodes(seed: int, train: int, val: int, test_nominal: int, test_anomalous: int, types: Sequence[str],
                  width: int, height: int, fps: int, short: bool, robot: str = "primitive",
                  camera: str = "head", depth: bool = False) -> list[EpisodeSpec]:
    """The episodes of a dataset: nominal train/val/test, then anomalous test episodes
    cycling through `types`."""
    specs: list[EpisodeSpec] = []
    for split, n in (("train", train), ("val", val)):
        specs += [EpisodeSpec(f"{split}_{i:04d}", split, i, None, seed, width, height, fps, short, robot,
                              camera, depth)
                  for i in range(n)]
    specs += [EpisodeSpec(f"test_{i:04d}", "test", i, None, seed, width, height, fps, short, robot, camera,
                          depth)
              for i in range(test_nominal)]
    for k in range(test_anomalous):
        i = test_nominal + k
        kind = types[k % len(types)]
        specs.append(EpisodeSpec(f"test_{i:04d}_{kind}", "test", i, kind, seed, width, height, fps, short, robot,
                                 camera, depth))
    return specs


def _work(job: tuple[EpisodeSpec, str]) -> EpisodeResult:
    spec, out = job
    return generate_episode(spec, Path(out) / spec.split)


def generate(out: Path, specs: list[EpisodeSpec], seed: int, workers: int,
             progress: bool = True) -> dict[str, Any]:
    """Generates every episode (in `workers` processes), the robot package, camera.json and
    dataset.json; returns the dataset description."""
    from tqdm import tqdm

    out.mkdir(parents=True, exist_ok=True)
    model = rb.ROBOTS[specs[0].robot if specs else "primitive"]
    camera = specs[0].camera if specs else "head"
    model.write_package(out / "robot", camera)
    if specs:
        spec = camera_spec(specs[0].width, specs[0].height, camera)
        (out / "camera.json").write_text(json.dumps(spec, indent=2) + "\n")
    start = time.perf_counter()
    jobs = [(s, str(out)) for s in specs]
    results: list[EpisodeResult] = []
    bar = tqdm(total=len(jobs), desc="episodes", unit="ep", disable=not progress)
    if workers <= 1 or len(jobs) <= 1:
        for job in jobs:
            results.append(_work(job))
            bar.update(1)
    else:
        ctx = multiprocessing.get_context("spawn")
        with ctx.Pool(min(workers, len(jobs))) as pool:
            for r in pool.imap_unordered(_work, jobs):
                results.append(r)
                bar.update(1)
    bar.close()
    order = {s.name: i for i, s in enumerate(specs)}
    results.sort(key=lambda r: order[r.name])
    first = specs[0] if specs else None
    dataset = {
        "generator": "vamos-sim",
        "generator_version": GENERATOR_VERSION,
        "seed": seed,
        "width": first.width if first else None,
        "height": first.height if first else None,
        "fps": first.fps if first else None,
        "short": first.short if first else False,
        "robot": f"robot/{model.name}.urdf",
        "camera": "camera.json",
        "camera_mount": camera,
        "depth_topic": DEPTH_TOPIC if first and first.depth else None,
        "counts": {split: sum(1 for s in specs if s.split == split) for split in ("train", "val", "test")},
        "anomalous": sum(1 for s in specs if s.anomaly),
        "episodes": [{"name": r.name, "split": r.split, "path": f"{r.split}/{r.name}.mcap",
                      "anomaly_type": r.anomaly, "duration_s": r.duration_s, "images": r.images,
                      "joint_states": r.joint_states, "intervals_ns": r.intervals_ns,
                      "draw": r.attempt, "anomaly_params": r.details, "task": r.task} for r in results],
    }
    (out / "dataset.json").write_text(json.dumps(dataset, indent=2) + "\n")
    elapsed = time.perf_counter() - start
    per = [r.seconds for r in results]
    dataset["_timing"] = {"total_s": elapsed, "per_episode_s": per, "cpu_s": [r.cpu_seconds for r in results],
                          "media_s": [r.duration_s for r in results]}
    return dataset


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``vamos-sim``."""
    parser = argparse.ArgumentParser(prog="vamos-sim", description=(__doc__ or "").split("\n\n")[0])
    add_version(parser)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    g = sub.add_parser("generate", help="generate a dataset of simulated episodes")
    g.add_argument("--out", type=Path, required=True, help="output folder")
    g.add_argument("--seed", type=int, default=0, help="dataset seed (default 0)")
    g.add_argument("--train", type=_count, default=None, help="nominal training episodes (default 40)")
    g.add_argument("--val", type=_count, default=None, help="nominal validation episodes (default 6)")
    g.add_argument("--test-nominal", type=_count, default=None, help="nominal test episodes (default 10)")
    g.add_argument("--test-anomalous", type=_count, default=None,
                   help="anomalous test episodes, cycling through --types (default 35)")
    g.add_argument("--types", type=_types, default=list(ANOMALY_TYPES),
                   help=f"anomaly types, comma-separated (default all: {','.join(ANOMALY_TYPES)})")
    g.add_argument("--workers", type=int, default=max(1, (multiprocessing.cpu_count() or 1)),
                   help="parallel worker processes (default: CPU count)")
    g.add_argument("--width", type=int, default=None, help="image width (default 640; smoke 160)")
    g.add_argument("--height", type=int, default=None, help="image height (default 480; smoke 120)")
    g.add_argument("--robot", choices=sorted(rb.ROBOTS), default="primitive",
                   help="primitive: the URDF-primitive 6-DoF arm (default); panda: pybullet_data's franka_panda "
                        "(7 DoF, meshes copied into DIR/robot/meshes), same head and camera")
    g.add_argument("--camera", choices=rb.CAMERAS, default="head",
                   help="head: on the robot's pan-tilt head, moving with it (default); fixed: fixed to the "
                        "world on a bracket above and left of the robot, looking at the shelf's front; wrist: on "
                        "the arm behind the fingers, looking along them (moves and turns with the tool)")
    g.add_argument("--depth", action="store_true",
                   help="also record a depth image registered to every image (/camera/depth/image_raw, 16UC1 "
                        "millimetres): set [episode.topics] depth to use it")
    g.add_argument("--fps", type=int, default=10, help="image rate, Hz; must divide 200 (default 10)")
    g.add_argument("--smoke", action="store_true",
                   help="a handful of short (~3 s), small (160x120) episodes: 2 train, 1 nominal and 2 anomalous test")
    g.add_argument("--no-progress", action="store_true", help="no progress bar")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``vamos-sim``."""
    args = build_parser().parse_args(argv)
    defaults = SMOKE_COUNTS if args.smoke else {"train": 40, "val": 6, "test_nominal": 10, "test_anomalous": 35}
    counts = {k: (getattr(args, k) if getattr(args, k) is not None else v) for k, v in defaults.items()}
    width = args.width or (SMOKE_SIZE[0] if args.smoke else 640)
    height = args.height or (SMOKE_SIZE[1] if args.smoke else 480)
    if width <= 0 or height <= 0:
        print("error: --width and --height must be positive", file=sys.stderr)
        return 2
    if args.fps <= 0 or PHYSICS_HZ % args.fps != 0:
        print(f"error: --fps {args.fps} must divide the physics rate, {PHYSICS_HZ} Hz (e.g. 5, 10, 20, 25, 40, 50)",
              file=sys.stderr)
        return 2
    if args.workers < 1:
        print("error: --workers must be at least 1", file=sys.stderr)
        return 2
    specs = plan_episodes(args.seed, counts["train"], counts["val"], counts["test_nominal"], counts["test_anomalous"],
                          args.types, width, height, args.fps, args.smoke, args.robot, args.camera,
                          args.depth)
    try:
        dataset = generate(args.out, specs, args.seed, args.workers, progress=not args.no_progress)
    except SimError as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    timing = dataset.pop("_timing")
    per = timing["per_episode_s"]
    n = max(len(per), 1)
    print(f"wrote {len(per)} episodes ({sum(timing['media_s']):.1f} s of recording, {width}x{height}) to {args.out} "
          f"in {timing['total_s']:.1f} s; per episode: {sum(per) / n:.1f} s wall, "
          f"{sum(timing['cpu_s']) / n:.1f} s CPU")
    return 0


if __name__ == "__main__":
    sys.exit(main())
