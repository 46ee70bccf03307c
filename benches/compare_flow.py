#!/usr/bin/env python3
"""Peer benchmark: vamos TV-L1 optical flow vs OpenCV, time and accuracy.

For each size and case, renders a synthetic pair with exact ground truth (the generator
of the golden fixtures, ``tests/fixtures/flowgen.py``, which mirrors
``crates/vamos-vision/src/synthetic.rs``), quantises it to 8-bit PNGs and runs:

* OpenCV DualTVL1 (``cv2.optflow.createOptFlow_DualTVL1()``, all defaults: tau 0.25,
  lambda 0.15, theta 0.3, nscales 5, warps 5, epsilon 0.01, inner 30, outer 10,
  scale step 0.8, gamma 0, median 5) with ``cv2.setNumThreads(N)`` for each N in
  ``--opencv-threads``;
* OpenCV DIS, preset MEDIUM (``cv2.DISOpticalFlow_create``), for context -- a much
  cheaper, less accurate method;
* ``vamos flow A.png B.png -o OUT.png --raw OUT.flo --preset P --threads N --repeat R
  --timing`` for each preset in ``--presets`` and N in ``--vamos-threads``.  vamos
  prints one JSON line ``{"width", "height", "preset", "threads", "repeat", "ms_min",
  "ms_median"}`` (flow computation only, no file I/O); its AEE is computed from the
  ``.flo`` it writes.

OpenCV times are taken in-process with ``time.perf_counter`` around ``calc`` on the
uint8 arrays (no file I/O either): one untimed warm-up call, then ``--repeat`` timed
calls; the table reports the minimum (and median).  AEE is the mean endpoint error
against the analytic ground truth over all pixels (the benchmark cases have no
occlusions).  "ratio" is the row's time over OpenCV DualTVL1's time at the same size,
case and thread count (or 1 thread when that count was not run).

Usage (from the repository root):
    cargo build --release
    python3 benches/compare_flow.py [--vamos target/release/vamos]
        [--sizes 160x120,320x240,640x480] [--cases smooth,similarity] [--repeat 3]
        [--opencv-threads 1,2] [--vamos-threads 1,2] [--presets default,realtime]
        [--skip-vamos] [--skip-dis] [--out benches/flow_comparison.md] [--workdir DIR]

Requires numpy and opencv-contrib-python-headless (for ``cv2.optflow``).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests" / "fixtures"))
import flowgen  # noqa: E402

import cv2  # noqa: E402


def parse_sizes(text: str) -> list[tuple[int, int]]:
    sizes = []
    for item in text.split(","):
        w, h = item.lower().strip().split("x")
        sizes.append((int(w), int(h)))
    return sizes


def parse_ints(text: str) -> list[int]:
    return [int(t) for t in text.split(",") if t.strip()]


def bench_motion(motion: dict, w: int, h: int, scaling: str) -> dict:
    """The benchmark's motion at ``w x h``.

    ``fixed``: the golden (160x120) parameters at every size, so the rotation and scale
    part of a similarity moves pixels further as the image grows (about 7, 14 and 27 px
    at the corners at 160, 320 and 640 wide).  ``pixels`` (default): rotation angle and
    scale change shrink by ``160 / w`` so the largest displacement stays about what it is
    at 160x120; translations stay in pixels, and the smooth field is normalised to
    3 px at every size anyway.
    """
    m = dict(motion)
    if scaling == "pixels" and m["type"] == "similarity":
        k = min(160.0 / w, 120.0 / h)
        m["rotation_deg"] = m["rotation_deg"] * k
        m["scale"] = 1.0 + (m["scale"] - 1.0) * k
    return m


def time_calls(fn, repeat: int) -> tuple[np.ndarray, list[float]]:
    """One warm-up call, then ``repeat`` timed calls; returns (result, times in ms)."""
    out = fn()
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return out, times


def run_vamos(binary: str, a_png: Path, b_png: Path, workdir: Path, preset: str,
              threads: int, repeat: int, tag: str) -> dict:
    """Runs the vamos CLI; returns its timing JSON plus the flow it wrote."""
    out_png = workdir / f"{tag}_vamos_{preset}_t{threads}.png"
    out_flo = workdir / f"{tag}_vamos_{preset}_t{threads}.flo"
    cmd = [binary, "flow", str(a_png), str(b_png), "-o", str(out_png), "--raw", str(out_flo),
           "--preset", preset, "--threads", str(threads), "--repeat", str(repeat), "--timing"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} exited {proc.returncode}: {proc.stderr.strip()[-500:]}")
    lines = [ln for ln in proc.stdout.splitlines() if ln.strip().startswith("{")]
    if not lines:
        raise RuntimeError(f"no timing JSON on stdout of {' '.join(cmd)}: {proc.stdout[-500:]!r}")
    info = json.loads(lines[-1])
    for key in ("width", "height", "preset", "threads", "repeat", "ms_min", "ms_median"):
        if key not in info:
            raise RuntimeError(f"timing JSON lacks {key!r}: {lines[-1]}")
    info["flow"] = flowgen.read_flo(out_flo)
    return info


def fmt(v, spec: str) -> str:
    return "n/a" if v is None else format(v, spec)


def main() -> int:
    ap = argparse.ArgumentParser(description="vamos vs OpenCV optical flow benchmark")
    ap.add_argument("--vamos", default=str(ROOT / "target" / "release" / "vamos"))
    ap.add_argument("--sizes", default="160x120,320x240,640x480")
    ap.add_argument("--cases", default="smooth,similarity",
                    help="comma list of: " + ",".join(flowgen.standard_cases(160, 120)))
    ap.add_argument("--repeat", type=int, default=3, help="timed runs per method (min reported)")
    ap.add_argument("--opencv-threads", default="1,2")
    ap.add_argument("--vamos-threads", default="1,2")
    ap.add_argument("--presets", default="default,realtime")
    ap.add_argument("--motion-scaling", choices=["pixels", "fixed"], default="pixels",
                    help="pixels: similarity displacements stay ~160x120-sized at every size; "
                         "fixed: same rotation/scale at every size (bigger displacements)")
    ap.add_argument("--skip-vamos", action="store_true")
    ap.add_argument("--skip-dis", action="store_true")
    ap.add_argument("--out", type=Path, default=ROOT / "benches" / "flow_comparison.md")
    ap.add_argument("--workdir", type=Path, help="keep the PNG/.flo files here")
    args = ap.parse_args()

    sizes = parse_sizes(args.sizes)
    case_names = [c.strip() for c in args.cases.split(",") if c.strip()]
    cv_threads = parse_ints(args.opencv_threads)
    vm_threads = parse_ints(args.vamos_threads)
    presets = [p.strip() for p in args.presets.split(",") if p.strip()]
    if not args.skip_vamos and not Path(args.vamos).is_file():
        ap.error(f"vamos binary {args.vamos} not found (build it, pass --vamos, or --skip-vamos)")

    tmp = None
    if args.workdir:
        workdir = args.workdir
        workdir.mkdir(parents=True, exist_ok=True)
    else:
        tmp = tempfile.TemporaryDirectory(prefix="vamos_flow_bench_")
        workdir = Path(tmp.name)

    load_at_start = os.getloadavg()[0]
    rows = []  # [size, case, gt_max, method, threads, ms_min, ms_median, aee, ratio]
    for w, h in sizes:
        cases = flowgen.standard_cases(w, h)
        for name in case_names:
            if name not in cases:
                ap.error(f"unknown case {name!r}")
            motion, seed = cases[name]
            motion = bench_motion(motion, w, h, args.motion_scaling)
            pair = flowgen.make_pair(w, h, motion, seed)
            a8, b8 = flowgen.quantise(pair.a), flowgen.quantise(pair.b)
            tag = f"{w}x{h}_{name}"
            a_png, b_png = workdir / f"{tag}_a.png", workdir / f"{tag}_b.png"
            cv2.imwrite(str(a_png), a8)
            cv2.imwrite(str(b_png), b8)
            gt, valid = pair.flow, pair.valid
            size = f"{w}x{h}"
            gt_max = float(np.hypot(gt[..., 0], gt[..., 1]).max())
            tvl1_ms: dict[int, float] = {}
            case_rows = []

            for n in cv_threads:
                cv2.setNumThreads(n)
                tvl1 = cv2.optflow.createOptFlow_DualTVL1()
                flow, times = time_calls(lambda: tvl1.calc(a8, b8, None), args.repeat)
                tvl1_ms[n] = min(times)
                case_rows.append([size, name, gt_max, "OpenCV DualTVL1", n, min(times),
                                  statistics.median(times), flowgen.aee(flow, gt, valid)])
                print(f"  {size} {name}: OpenCV DualTVL1 t{n} {min(times):.1f} ms", file=sys.stderr)

            if not args.skip_dis:
                for n in cv_threads:
                    cv2.setNumThreads(n)
                    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
                    flow, times = time_calls(lambda: dis.calc(a8, b8, None), args.repeat)
                    case_rows.append([size, name, gt_max, "OpenCV DIS medium", n, min(times),
                                      statistics.median(times), flowgen.aee(flow, gt, valid)])

            if not args.skip_vamos:
                for preset in presets:
                    for n in vm_threads:
                        try:
                            info = run_vamos(args.vamos, a_png, b_png, workdir, preset, n,
                                             args.repeat, tag)
                        except (RuntimeError, ValueError, OSError) as e:
                            print(f"vamos {preset} t{n} on {tag} failed: {e}", file=sys.stderr)
                            case_rows.append([size, name, gt_max, f"vamos {preset}", n, None, None, None])
                            continue
                        if (info["width"], info["height"]) != (w, h) or info["flow"].shape[:2] != (h, w):
                            print(f"vamos {preset} t{n} on {tag}: size mismatch {info['width']}x"
                                  f"{info['height']}", file=sys.stderr)
                        case_rows.append([size, name, gt_max, f"vamos {preset}", n, float(info["ms_min"]),
                                          float(info["ms_median"]), flowgen.aee(info["flow"], gt, valid)])

            for r in case_rows:
                ref = tvl1_ms.get(r[4], tvl1_ms.get(1))
                r.append(None if (r[5] is None or not ref) else r[5] / ref)
            rows.extend(case_rows)

    header = ["size", "case", "max GT (px)", "method", "threads", "ms/pair (min)", "ms (median)",
              "AEE vs GT (px)", "time / OpenCV TVL1"]
    lines = [
        "# Optical flow: vamos vs OpenCV",
        "",
        f"Generated by `benches/compare_flow.py` on {time.strftime('%Y-%m-%d')}: "
        f"OpenCV {cv2.__version__}, numpy {np.__version__}, Python {platform.python_version()}, "
        f"{platform.machine()}, {os.cpu_count()} logical CPUs, load average at start "
        f"{load_at_start:.2f}.",
        f"Cases: {', '.join(case_names)} (synthetic pairs from `tests/fixtures/flowgen.py`). "
        f"Timings: min (and median) of {args.repeat} runs after a warm-up, flow computation "
        "only; vamos times are its own `--timing` report. DualTVL1 uses all OpenCV defaults; "
        "DIS is preset MEDIUM. Ratio: row time / OpenCV DualTVL1 time, same size, case and "
        f"thread count. Motion scaling: `{args.motion_scaling}` (see `bench_motion`).",
        "",
        "| " + " | ".join(header) + " |",
        "|" + "|".join(["---", "---", "---:", "---"] + ["---:"] * 5) + "|",
    ]
    for size, case, gt_max, method, n, ms, med, err, ratio in rows:
        lines.append(f"| {size} | {case} | {gt_max:.1f} | {method} | {n} | {fmt(ms, '.1f')} | {fmt(med, '.1f')} | "
                     f"{fmt(err, '.4f')} | {fmt(ratio, '.3g')} |")
    if args.skip_vamos:
        lines += ["", "_vamos rows skipped (`--skip-vamos`)._"]
    text = "\n".join(lines) + "\n"
    print(text)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text)
    print(f"wrote {args.out}", file=sys.stderr)
    if tmp is not None:
        tmp.cleanup()
    return 0


if __name__ == "__main__":
    sys.exit(main())
