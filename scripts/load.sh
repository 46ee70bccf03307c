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
# with matplotlib (PYTHON names an interpreter that has it), OUT_DIR/load.png (robots vs
# latency and CPU).
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

"${PYTHON:-python3}" "$root/scripts/lib/load_report.py" "$out"
