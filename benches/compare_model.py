#!/usr/bin/env python3
"""Times the flow predictor's work in Python onnxruntime, to compare with benches/model.rs.

Same work as the Rust bench: encoder at batch 1 and B+1, head at batch 1 and (B+1)*M, and
the per-frame cost of the cached predictor (encoder once + one head call + MSE/argmin in
numpy) and of the naive loop (encoder and head per offset). Prints the minimum over
repeats in milliseconds, one JSON object.

    python3 benches/compare_model.py [BUNDLE] [--threads 1] [--samples M] [--repeat 50]
"""

import argparse
import json
import os
import time
import zipfile

import numpy as np
import onnxruntime as ort


def best_ms(fn, repeat):
    fn()
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return min(times)


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    ap = argparse.ArgumentParser()
    ap.add_argument("bundle", nargs="?", default=os.environ.get(
        "VAMOS_BENCH_MODEL", os.path.join(here, "..", "tests/fixtures/model/valid.vamos")))
    ap.add_argument("--threads", type=int, default=int(os.environ.get("VAMOS_BENCH_THREADS", 1)))
    ap.add_argument("--samples", type=int, default=int(os.environ.get("VAMOS_BENCH_SAMPLES", 0)))
    ap.add_argument("--repeat", type=int, default=50)
    args = ap.parse_args()
    with zipfile.ZipFile(args.bundle) as z:
        man = json.loads(z.read("manifest.json"))
        enc_bytes, head_bytes = z.read("encoder.onnx"), z.read("head.onnx")
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = args.threads
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    enc = ort.InferenceSession(enc_bytes, opts, providers=["CPUExecutionProvider"])
    head = ort.InferenceSession(head_bytes, opts, providers=["CPUExecutionProvider"])
    a, b = man["temporal"]["a"], man["temporal"]["b"]
    m = args.samples or man["temporal"]["m"]
    s = man["input"]["size"]
    offsets, rows = b + 1, (b + 1) * m
    rng = np.random.default_rng(3)
    frames = np.clip(rng.standard_normal((a + b + 2, 2, s, s)) * 0.2, -0.5, 0.5).astype(np.float32)
    out = {"bundle": os.path.abspath(args.bundle), "threads": args.threads, "a": a, "b": b, "m": m,
           "onnxruntime": ort.__version__}
    for batch in (1, offsets):
        x = frames[:batch]
        out[f"encoder_{batch}_ms"] = best_ms(lambda: enc.run(None, {"flow": x}), args.repeat)
    f, mu, ls = enc.run(None, {"flow": frames[:1]})
    for batch in (1, rows):
        fb = np.repeat(f, batch, axis=0)
        zb = np.repeat(mu, batch, axis=0)
        out[f"head_{batch}_ms"] = best_ms(lambda: head.run(None, {"features": fb, "z": zb}), args.repeat)

    # Cached predictor: encoder outputs of the past frames are kept.
    cache = [enc.run(None, {"flow": frames[i:i + 1]}) for i in range(a + b)]
    current = frames[a + b]
    t = a + b

    def score(pred):
        err = ((pred - current[None]) ** 2).reshape(pred.shape[0], -1).mean(axis=1)
        k = int(np.argmin(err))
        return err[k], k

    def cached():
        feats, zs = [], []
        for n in range(a, a + b + 1):
            cf, cmu, cls = cache[t - n]
            eps = rng.standard_normal((m, cmu.shape[1])).astype(np.float32)
            feats.append(np.repeat(cf, m, axis=0))
            zs.append(cmu + np.exp(cls) * eps)
        pred = head.run(None, {"features": np.concatenate(feats), "z": np.concatenate(zs)})[0]
        enc.run(None, {"flow": current[None]})
        return score(pred)

    def naive():
        best = None
        for n in range(a, a + b + 1):
            cf, cmu, cls = enc.run(None, {"flow": frames[t - n][None]})
            eps = rng.standard_normal((m, cmu.shape[1])).astype(np.float32)
            pred = head.run(None, {"features": np.repeat(cf, m, axis=0), "z": cmu + np.exp(cls) * eps})[0]
            e = score(pred)
            best = e if best is None or e[0] < best[0] else best
        return best

    out["frame_cached_ms"] = best_ms(cached, args.repeat)
    out["frame_naive_ms"] = best_ms(naive, args.repeat)
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
