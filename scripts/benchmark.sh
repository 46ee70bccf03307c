#!/bin/sh
# The simulated benchmark in one command: generate the dataset with vamos-sim, train one
# flow predictor per input-flow variant, calibrate the masked profile, then run
# `vamos eval --ablation` on the test episodes (the paper's table, on simulated data).
#
#   scripts/benchmark.sh OUT_DIR
#
# Needs the release binary (cargo build --release) and the Python package with its `sim`
# and `train` extras (pip install './clients/python[sim,train]'). Sizes come from the
# environment (defaults in brackets): TRAIN [40], VAL [20], TEST_NOMINAL [10],
# TEST_ANOMALOUS [35] episodes; WIDTH x HEIGHT [320 x 240]; SEED [7]; EPOCHS [12];
# NET_WIDTH [0.5] (the U-Net's width multiplier; 1.0 is the paper's network); ALPHA [0.1]
# (conformal false-alarm budget per nominal episode: with VAL >= 19 the threshold is not
# simply the largest held-out maximum); VARIANTS [all four]; DEVICE [auto]
# (vamos-train's --device: cuda trains the paper-size network in minutes).
# On a 2-core CPU machine the defaults of 2026-12-02 (VAL=6 ALPHA=0.2, the defaults until
# 2026-12-06; the benchmark tables of docs/detection-history.md) took about 100 minutes,
# most of it training.
# Episodes are seeded per split and index: VAL=20 adds 14 validation episodes and leaves
# the first 6 and every training and test episode as they were.
# Results: OUT_DIR/eval.json, OUT_DIR/ablation.md, OUT_DIR/plots/.
set -eu
out=${1:?usage: scripts/benchmark.sh OUT_DIR}
root=$(cd "$(dirname "$0")/.." && pwd)
vamos=${VAMOS:-"$root/target/release/vamos"}
sim=${VAMOS_SIM:-vamos-sim}
train=${VAMOS_TRAIN:-vamos-train}
TRAIN=${TRAIN:-40}; VAL=${VAL:-20}; TEST_NOMINAL=${TEST_NOMINAL:-10}
TEST_ANOMALOUS=${TEST_ANOMALOUS:-35}; WIDTH=${WIDTH:-320}; HEIGHT=${HEIGHT:-240}
SEED=${SEED:-7}; EPOCHS=${EPOCHS:-12}; NET_WIDTH=${NET_WIDTH:-0.5}; ALPHA=${ALPHA:-0.1}
VARIANTS=${VARIANTS:-"plain registered masked masked_registered"}; DEVICE=${DEVICE:-auto}
workers=$(nproc 2>/dev/null || echo 2)
mkdir -p "$out"
out=$(cd "$out" && pwd)
log() { echo "== $(date -u +%H:%M:%S) $*"; }

if [ ! -f "$out/sim/dataset.json" ]; then
    log "simulating $TRAIN train, $VAL validation, $TEST_NOMINAL + $TEST_ANOMALOUS test episodes at ${WIDTH}x$HEIGHT"
    "$sim" generate --out "$out/sim" --seed "$SEED" --width "$WIDTH" --height "$HEIGHT" \
        --train "$TRAIN" --val "$VAL" --test-nominal "$TEST_NOMINAL" \
        --test-anomalous "$TEST_ANOMALOUS" --workers "$workers" --no-progress
fi

profile() { # VARIANT [MODEL]
    {
        echo 'name = "sim-benchmark"'
        echo "robot = \"$out/sim/robot/vamos_arm.urdf\""
        echo "camera = \"$out/sim/camera.json\""
        [ -n "${2:-}" ] && echo "model = \"$2\""
        echo 'flow_preset = "realtime"'
        echo 'alarm = "conformal"'
        echo '[pipeline]'
        echo 'stride = 1'
        # The paper's rule, as the paper's table measures it (`auto` is the calibrated
        # fusion since 2026-12-06; scripts/detectors.sh has those rows).
        echo 'fusion = "paper"'
        echo '[pipeline.frames]'
        echo "width = $WIDTH"
        echo "height = $HEIGHT"
        echo "variant = \"$1\""
    }
}

variant_models=""
for v in $VARIANTS; do
    if [ ! -f "$out/run_$v/model.vamos" ]; then
        profile "$v" > "$out/export_$v.toml"
        log "exporting the $v training set"
        "$vamos" export-dataset "$out/sim/train" -o "$out/dataset_$v" --profile "$out/export_$v.toml"
        log "training the $v model ($EPOCHS epochs, width $NET_WIDTH)"
        "$train" fit "$out/dataset_$v" -o "$out/run_$v" --width "$NET_WIDTH" --epochs "$EPOCHS" \
            --seed 1 --name "sim-$v" --device "$DEVICE" --no-progress
    fi
    [ "$v" != masked ] && variant_models="$variant_models --variant-model $v=$out/run_$v/model.vamos"
done

main=masked
case " $VARIANTS " in *" masked "*) ;; *) main=$(echo "$VARIANTS" | awk '{print $1}') ;; esac
profile "$main" "$out/run_$main/model.vamos" > "$out/profile.toml"
log "calibrating the $main profile (training maxima; conformal alpha $ALPHA on $VAL held-out episodes)"
"$vamos" calibrate --profile "$out/profile.toml" "$out/sim/train" --holdout "$out/sim/val" \
    --alpha "$ALPHA" > "$out/calibration.out"
log "evaluating on the test episodes, with the ablation table"
# shellcheck disable=SC2086
"$vamos" eval --profile "$out/profile.toml" --episodes "$out/sim/test" --json "$out/eval.json" \
    --plots "$out/plots" --ablation "$out/ablation.md" $variant_models > /dev/null
log "done: $out/eval.json, $out/ablation.md, $out/plots/"
cat "$out/ablation.md"
