#!/usr/bin/env bash
# A soak run of the service: N simulated robots streaming with churn (one session per
# replayed episode) against `vamos serve`, the stored model re-uploaded and made active
# with `reload_sessions` every SWAP_EVERY seconds (running sessions move to it), then the
# loadgen report (rate, latency percentiles, drops, errors, the server's RSS and CPU per
# interval) and the model swaps' outcome. Needs the release binary (cargo build --release).
#
#   ROBOTS=8 DURATION=1800 SWAP_EVERY=300 scripts/soak.sh [OUT_DIR]
#
# Figures of the runs made: benches/README.md#reliability.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

ROBOTS="${ROBOTS:-8}"
DURATION="${DURATION:-1800}"
SWAP_EVERY="${SWAP_EVERY:-300}"
SAMPLE_EVERY="${SAMPLE_EVERY:-60}"
OUT="${1:-$(mktemp -d /tmp/vamos-soak.XXXXXX)}"
BIN="${VAMOS_BIN:-target/release/vamos}"
FIX=tests/fixtures/sim
MODEL=tests/fixtures/model/tiny_trained.vamos
ADMIN="soak-admin-$RANDOM$RANDOM"
ROBOT="soak-robot-$RANDOM$RANDOM"
mkdir -p "$OUT"

port() { python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'; }
GRPC="127.0.0.1:$(port)"
REST="127.0.0.1:$(port)"

VAMOS_ADMIN_TOKEN="$ADMIN" VAMOS_ROBOT_TOKEN="$ROBOT" VAMOS_SERVICE__QUEUE_DEPTH=16 \
    "$BIN" --log-format json --log-level warn serve --grpc-addr "$GRPC" --rest-addr "$REST" \
    --data-dir "$OUT/data" 2> "$OUT/server.log" &
SERVER=$!
trap 'kill $SERVER 2>/dev/null || true; kill $SWAPPER 2>/dev/null || true' EXIT
for _ in $(seq 100); do
    curl -fs "http://$REST/readyz" > /dev/null 2>&1 && break
    sleep 0.2
done

api() { curl -fsS -H "Authorization: Bearer $ADMIN" "$@"; }
api -X PUT --data-binary "@$FIX/robot/vamos_arm.urdf" "http://$REST/v1/robots/arm?format=urdf" > /dev/null
api -X PUT --data-binary "@$MODEL" "http://$REST/v1/models/tiny" > /dev/null
python3 - "$FIX/camera.json" > "$OUT/profile.json" <<'EOF'
import json, sys
camera = json.load(open(sys.argv[1]))
print(json.dumps({"robot": "arm", "camera": camera, "model": {"name": "tiny"},
                  "flow_preset": "realtime",
                  "pipeline": {"stride": 1, "frames": {"width": 160, "height": 120,
                                                       "variant": "masked"}}}))
EOF
api -X PUT -H 'Content-Type: application/json' --data-binary "@$OUT/profile.json" \
    "http://$REST/v1/profiles/soak" > /dev/null

# The model swaps: a new version every SWAP_EVERY seconds, active at once, running
# sessions moved to it.
(
    n=0
    while sleep "$SWAP_EVERY"; do
        v=$(api -X PUT --data-binary "@$MODEL" "http://$REST/v1/models/tiny" |
            python3 -c 'import json,sys; print(json.load(sys.stdin)["version"])')
        api -X POST -H 'Content-Type: application/json' \
            -d "{\"version\": $v, \"reload_sessions\": true}" \
            "http://$REST/v1/models/tiny/active" > /dev/null
        n=$((n + 1))
        echo "$(date -u +%FT%TZ) swap $n: version $v active" >> "$OUT/swaps.log"
    done
) &
SWAPPER=$!

VAMOS_LOADGEN_TOKEN="$ROBOT" "$BIN" loadgen --server "http://$GRPC" --profile soak \
    --robots "$ROBOTS" --duration "$DURATION" --sample-every "$SAMPLE_EVERY" \
    --metrics "http://$REST/metrics" $FIX/test/*.mcap > "$OUT/loadgen.json"
kill $SWAPPER 2>/dev/null || true
curl -fs "http://$REST/metrics" > "$OUT/metrics.txt"
echo "report: $OUT/loadgen.json; swaps: $(wc -l < "$OUT/swaps.log" 2>/dev/null || echo 0)"
grep -E '^vamos_(worker_restarts|scoring_panics|frames_dropped|message_errors)' "$OUT/metrics.txt" || true
