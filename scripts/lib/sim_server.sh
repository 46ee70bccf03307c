# Sourced by scripts/soak.sh and scripts/swap_memory.sh: starts `vamos serve` on free
# loopback ports with fresh tokens and a data directory under $OUT, stores the simulated
# arm, the tiny model and profile $PROFILE (realtime TV-L1, masked, 160x120) in it, and
# defines `api` (admin REST calls) and `swap` (upload the model again, make it active and
# move the running sessions to it). Sets SERVER (its pid), GRPC, REST, ROBOT (the robot
# token). Needs BIN, OUT, PROFILE; extra environment reaches the server.

FIX=tests/fixtures/sim
MODEL=tests/fixtures/model/tiny_trained.vamos
ADMIN="sim-admin-$RANDOM$RANDOM"
ROBOT="sim-robot-$RANDOM$RANDOM"

port() { python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'; }
GRPC="127.0.0.1:$(port)"
REST="127.0.0.1:$(port)"

VAMOS_ADMIN_TOKEN="$ADMIN" VAMOS_ROBOT_TOKEN="$ROBOT" VAMOS_SERVICE__QUEUE_DEPTH=16 \
    "$BIN" --log-format json --log-level warn serve --grpc-addr "$GRPC" --rest-addr "$REST" \
    --data-dir "$OUT/data" 2> "$OUT/server.log" &
SERVER=$!
for _ in $(seq 100); do
    curl -fs "http://$REST/readyz" > /dev/null 2>&1 && break
    sleep 0.2
done

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
    "http://$REST/v1/profiles/$PROFILE" > /dev/null

# Prints the version made active.
swap() {
    local v
    v=$(api -X PUT --data-binary "@$MODEL" "http://$REST/v1/models/tiny" |
        python3 -c 'import json,sys; print(json.load(sys.stdin)["version"])')
    api -X POST -H 'Content-Type: application/json' \
        -d "{\"version\": $v, \"reload_sessions\": true}" \
        "http://$REST/v1/models/tiny/active" > /dev/null
    echo "$v"
}
