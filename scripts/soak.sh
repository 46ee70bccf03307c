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
PROFILE=soak
mkdir -p "$OUT"
SERVER=
SWAPPER=
trap 'kill $SERVER 2>/dev/null || true; kill $SWAPPER 2>/dev/null || true' EXIT
source scripts/lib/sim_server.sh

# The model swaps: a new version every SWAP_EVERY seconds, active at once, running
# sessions moved to it.
(
    n=0
    while sleep "$SWAP_EVERY"; do
        v=$(swap)
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
