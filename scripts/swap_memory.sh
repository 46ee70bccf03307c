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
OUT="$(mktemp -d /tmp/vamos-swap-memory.XXXXXX)"
PROFILE=probe
SERVER=
trap 'kill $SERVER 2>/dev/null || true' EXIT
source scripts/lib/sim_server.sh

anon() {
    echo "$(date -u +%T) $1: $(grep -E '^Anonymous:' "/proc/$SERVER/smaps_rollup" | tr -s ' ')"
}
anon "idle, before any session"
for round in $(seq "$ROUNDS"); do
    VAMOS_LOADGEN_TOKEN="$ROBOT" "$BIN" loadgen --server "http://$GRPC" --profile probe \
        --robots 8 --duration 80 --sample-every 30 $FIX/test/*.mcap > "$OUT/loadgen-$round.json" &
    LOAD=$!
    sleep 20
    anon "round $round, under load"
    if [ "$round" -gt 1 ] && [ "$SWAPS" != 0 ]; then
        echo "$(date -u +%T) swap: version $(swap) active"
    fi
    sleep 30
    anon "round $round, 30 s later"
    wait $LOAD
    sleep 35
    anon "round $round, idle"
done
