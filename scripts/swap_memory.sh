#!/usr/bin/env bash
# What model swaps leave in the server's memory: ROUNDS rounds of 80 s of load (8 robots,
# tiny model, 160x120) on one `vamos serve`; from round 2 on a model swap (upload, make
# active, move the running sessions) 20 s into each round unless SWAPS=0. Prints the
# server's anonymous memory (/proc/PID/smaps_rollup) under load, 30 s after the swap, and
# 35 s after the round's load ended (every session closed, the heap trimmed). Needs the
# release binary (cargo build --release); Linux only.
#
#   ROUNDS=4 SWAPS=1 scripts/swap_memory.sh
#
# Figures of the runs made: benches/README.md#reliability.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

ROUNDS="${ROUNDS:-4}"
SWAPS="${SWAPS:-1}"
BIN="${VAMOS_BIN:-target/release/vamos}"
FIX=tests/fixtures/sim
MODEL=tests/fixtures/model/tiny_trained.vamos
OUT="$(mktemp -d /tmp/vamos-swap-memory.XXXXXX)"
ADMIN="swap-admin-$RANDOM$RANDOM"
ROBOT="swap-robot-$RANDOM$RANDOM"

port() { python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'; }
GRPC="127.0.0.1:$(port)"
REST="127.0.0.1:$(port)"
VAMOS_ADMIN_TOKEN="$ADMIN" VAMOS_ROBOT_TOKEN="$ROBOT" VAMOS_SERVICE__QUEUE_DEPTH=16 \
    "$BIN" --log-level warn serve --grpc-addr "$GRPC" --rest-addr "$REST" \
    --data-dir "$OUT/data" 2> "$OUT/server.log" &
SERVER=$!
trap 'kill $SERVER 2>/dev/null || true' EXIT
for _ in $(seq 100); do
    curl -fs "http://$REST/readyz" > /dev/null 2>&1 && break
    sleep 0.2
done

anon() {
    echo "$(date -u +%T) $1: $(grep -E '^Anonymous:' "/proc/$SERVER/smaps_rollup" | tr -s ' ')"
}
api() { curl -fsS -H "Authorization: Bearer $ADMIN" "$@"; }
api -X PUT --data-binary "@$FIX/robot/vamos_arm.urdf" "http://$REST/v1/robots/arm?format=urdf" > /dev/null
api -X PUT --data-binary "@$MODEL" "http://$REST/v1/models/tiny" > /dev/null
python3 - "$FIX/camera.json" > "$OUT/profile.json" <<'PY'
import json, sys
camera = json.load(open(sys.argv[1]))
print(json.dumps({"robot": "arm", "camera": camera, "model": {"name": "tiny"},
                  "flow_preset": "realtime",
                  "pipeline": {"stride": 1, "frames": {"width": 160, "height": 120,
                                                       "variant": "masked"}}}))
PY
api -X PUT -H 'Content-Type: application/json' --data-binary "@$OUT/profile.json" \
    "http://$REST/v1/profiles/probe" > /dev/null

swap() {
    v=$(api -X PUT --data-binary "@$MODEL" "http://$REST/v1/models/tiny" |
        python3 -c 'import json,sys; print(json.load(sys.stdin)["version"])')
    api -X POST -H 'Content-Type: application/json' \
        -d "{\"version\": $v, \"reload_sessions\": true}" \
        "http://$REST/v1/models/tiny/active" > /dev/null
    echo "$(date -u +%T) swap: version $v active"
}

anon "idle, before any session"
for round in $(seq "$ROUNDS"); do
    VAMOS_LOADGEN_TOKEN="$ROBOT" "$BIN" loadgen --server "http://$GRPC" --profile probe \
        --robots 8 --duration 80 --sample-every 30 $FIX/test/*.mcap > "$OUT/loadgen-$round.json" &
    LOAD=$!
    sleep 20
    anon "round $round, under load"
    if [ "$round" -gt 1 ] && [ "$SWAPS" != 0 ]; then swap; fi
    sleep 30
    anon "round $round, 30 s later"
    wait $LOAD
    sleep 35
    anon "round $round, idle"
done
