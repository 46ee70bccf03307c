#!/bin/sh
# The load users run, in one command: 640x480 JPEG episodes processed at 320x240, the
# default detectors calibrated, session recording on; `vamos loadgen` with more and more
# robots against one `vamos serve`, for the default TV-L1 preset (`realtime`) and for
# OpenCV's parameters (`flow_preset = "default"`, the default until 2026-12-07).
#
#   scripts/load.sh OUT_DIR
#
# Needs the release binary (cargo build --release) and vamos-sim (pip install
# './clients/python[sim]'). From the environment (defaults in brackets): ROBOTS [1 2 4 6 8
# 10 12 16] for the default profile, OPENCV_ROBOTS [1 2] for OpenCV's, DURATION [20] s per
# run, QUALITY [90] (JPEG), SIM [OUT_DIR/sim] (an existing 640x480 dataset is reused).
# Results: OUT_DIR/runs/PROFILE-N.json (loadgen's report), OUT_DIR/load.md (a table) and,
# with matplotlib, OUT_DIR/load.png (robots vs latency and CPU).
set -eu
out=${1:?usage: scripts/load.sh OUT_DIR}
root=$(cd "$(dirname "$0")/.." && pwd)
vamos=${VAMOS:-"$root/target/release/vamos"}
sim_cmd=${VAMOS_SIM:-vamos-sim}
ROBOTS=${ROBOTS:-"1 2 4 6 8 10 12 16"}
OPENCV_ROBOTS=${OPENCV_ROBOTS:-"1 2"}
DURATION=${DURATION:-20}
QUALITY=${QUALITY:-90}
mkdir -p "$out/runs"
out=$(cd "$out" && pwd)
sim=${SIM:-"$out/sim"}
log() { echo "== $(date -u +%H:%M:%S) $*"; }

if [ ! -f "$sim/dataset.json" ]; then
    log "simulating 640x480 episodes"
    "$sim_cmd" generate --out "$sim" --seed 21 --width 640 --height 480 --train 8 --val 6 \
        --test-nominal 4 --test-anomalous 3 --no-progress
fi
for split in train val test; do
    mkdir -p "$out/jpeg/$split"
    for f in "$sim/$split"/*.mcap; do
        b=$(basename "$f" .mcap)
        [ -f "$out/jpeg/$split/$b.mcap" ] && continue
        "$vamos" episode copy --jpeg "$QUALITY" "$f" "$out/jpeg/$split/$b.mcap" > /dev/null
        cp "$sim/$split/$b.labels.json" "$out/jpeg/$split/" 2> /dev/null || true
    done
done

urdf=$(ls "$sim"/robot/*.urdf | head -n 1)
for p in default opencv; do
    preset=
    [ "$p" = opencv ] && preset='flow_preset = "default"'
    cat > "$out/load-$p.toml" <<TOML
name = "load-$p"
robot = "$urdf"
camera = "$sim/camera.json"
$preset
alarm = "conformal"
TOML
    if [ ! -f "$out/load-$p.calibration.json" ]; then
        log "calibrating load-$p"
        "$vamos" calibrate --profile "$out/load-$p.toml" "$out/jpeg/train" \
            --holdout "$out/jpeg/val" --no-progress > /dev/null 2> "$out/calibrate-$p.log"
    fi
done

port_grpc=${GRPC_PORT:-18081}
port_rest=${REST_PORT:-18080}
rm -rf "$out/data"
VAMOS_SERVICE__GRPC_ADDR=127.0.0.1:$port_grpc VAMOS_SERVICE__REST_ADDR=127.0.0.1:$port_rest \
    "$vamos" serve --profile "$out/load-default.toml" --profile "$out/load-opencv.toml" \
    --data-dir "$out/data" > "$out/serve.log" 2>&1 &
server=$!
trap 'kill $server 2> /dev/null || true' EXIT INT TERM
sleep 3
run() { # PROFILE ROBOTS
    log "load-$1 with $2 robot(s) for $DURATION s"
    "$vamos" loadgen --server "http://127.0.0.1:$port_grpc" --profile "load-$1" --robots "$2" \
        --duration "$DURATION" --metrics "http://127.0.0.1:$port_rest/metrics" \
        "$out/jpeg/test"/*.mcap > "$out/runs/$1-$2.json" 2> "$out/runs/$1-$2.err"
}
for n in $ROBOTS; do run default "$n"; done
for n in $OPENCV_ROBOTS; do run opencv "$n"; done

python3 - "$out" <<'PY'
import glob, json, os, sys
out = sys.argv[1]
rows = []
for path in glob.glob(os.path.join(out, "runs", "*.json")):
    r = json.load(open(path))
    name = os.path.basename(path)[:-5].rsplit("-", 1)[0]
    s = r.get("server") or {}
    rows.append((name, r["robots"], r))
rows.sort(key=lambda t: (t[0], t[1]))
lines = ["| profile | robots | admitted at a time | scores/s per robot | dropped | p50 / p99 latency | server CPU (cores) | refused opens | RSS peak |",
         "|---|---|---|---|---|---|---|---|---|"]
for name, n, r in rows:
    s = r.get("server") or {}
    lat = r["latency_ms"]
    rate = r["image_rate_hz_per_robot"]
    admitted = r["scores_per_s"] / rate if rate else float("nan")
    lines.append(f"| {name} | {n} | {admitted:.1f} | {r['scores_per_s_per_robot']:.2f} | {r['dropped_reported']} | "
                 f"{lat['p50']} / {lat['p99']} ms | {s.get('cpu_cores_busy', float('nan')):.2f} | {r['error_count']} | {s.get('rss_mib_peak')} MiB |")
stages = {}
for name, n, r in rows:
    if n == 1:
        stages[name] = (r.get("server") or {}).get("stage_ms", {})
lines.append("")
lines.append("Mean ms per frame of each stage, one robot:")
lines.append("")
keys = sorted({k for v in stages.values() for k in v}, key=lambda k: -max(v.get(k, 0) for v in stages.values()))
lines.append("| profile | " + " | ".join(keys) + " |")
lines.append("|---" * (len(keys) + 1) + "|")
for name, v in sorted(stages.items()):
    lines.append(f"| {name} | " + " | ".join(str(v.get(k, "")) for k in keys) + " |")
open(os.path.join(out, "load.md"), "w").write("\n".join(lines) + "\n")
print("\n".join(lines))
try:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
except ImportError:
    sys.exit(0)
fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
for name in sorted({t[0] for t in rows}):
    pts = [(n, r) for m, n, r in rows if m == name]
    ns = [n for n, _ in pts]
    a.plot(ns, [r["latency_ms"]["p50"] for _, r in pts], "o-", label=f"{name} p50")
    a.plot(ns, [r["latency_ms"]["p99"] for _, r in pts], "s--", label=f"{name} p99")
    b.plot(ns, [(r.get("server") or {}).get("cpu_cores_busy", 0) for _, r in pts], "o-", label=name)
a.set_xlabel("robots streaming 10 Hz"); a.set_ylabel("latency, ms"); a.set_yscale("log"); a.legend(fontsize=8)
b.set_xlabel("robots streaming 10 Hz"); b.set_ylabel("server CPU, cores"); b.axhline(1.6, color="gray", ls=":", label="admission_load x workers"); b.legend(fontsize=8)
fig.tight_layout()
fig.savefig(os.path.join(out, "load.png"), dpi=100)
PY
