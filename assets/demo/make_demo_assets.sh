#!/bin/sh
# Regenerates the assets `vamos demo` embeds (every file in this folder except *.sh, *.md
# and dotfiles is compiled into the binary by build.rs):
#   robot/           the simulator's URDF-primitive arm with its pan-tilt head camera
#   camera.json      its camera
#   model.vamos      a small probabilistic U-Net trained by vamos-train on nominal
#                    simulated episodes (exported with vamos export-dataset)
#   profile.toml     the demo profile; profile.calibration.json: its thresholds, calibrated
#                    by vamos calibrate on the training episodes + held-out nominal ones
#   profile-no-model.toml (+ .calibration.json): the same without the model, for a
#                    machine without ONNX Runtime
#   episodes/        labelled test episodes (2 nominal, 5 anomalous), ROS 2 bags in MCAP
# Everything is seeded; the data come from `vamos-sim` (160x120, 10 Hz).
#
# Needs the release binary (cargo build --release) and the Python package with its `sim`
# and `train` extras: pip install './clients/python[sim,train]'. Takes ~10 min on 2 cores.
# Environment: VAMOS (binary), VAMOS_SIM, VAMOS_TRAIN (commands), WORK (keep the
# intermediate files there instead of a temporary folder).
set -eu
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../.." && pwd)
vamos=${VAMOS:-"$root/target/release/vamos"}
sim=${VAMOS_SIM:-vamos-sim}
train=${VAMOS_TRAIN:-vamos-train}
work=${WORK:-$(mktemp -d)}
mkdir -p "$work"
echo "work folder: $work"

"$sim" generate --out "$work/sim" --seed 2026 --width 160 --height 120 \
    --train 30 --val 10 --test-nominal 2 --test-anomalous 5 \
    --types book_falls,book_slips,camera_occluded,external_push,sensor_fault \
    --workers 2 --no-progress

assets="$work/assets"
rm -rf "$assets"
mkdir -p "$assets/episodes"
cp -r "$work/sim/robot" "$assets/robot"
cp "$work/sim/camera.json" "$assets/camera.json"
profile_head='name = "demo"
robot = "robot/vamos_arm.urdf"
camera = "camera.json"'
profile_tail='flow_preset = "realtime"
# The conformal threshold: at most ~10 % of nominal episodes raise a false alarm.
alarm = "conformal"

[pipeline]
stride = 1
# Every detector calibrated on the nominal runs and fused ("paper": the rule of the paper).
fusion = "calibrated"

[pipeline.frames]
width = 160
height = 120
variant = "masked"'
printf '%s\n%s\n' "$profile_head" "$profile_tail" > "$assets/profile.toml"

"$vamos" export-dataset "$work/sim/train" -o "$work/dataset" --profile "$assets/profile.toml"
"$train" fit "$work/dataset" -o "$work/run" --filters 8,16,32,32 --epochs 20 --batch-size 32 \
    --lr 1e-3 --seed 1 --name vamos-demo-sim --threads 2 --no-progress
cp "$work/run/model.vamos" "$assets/model.vamos"
printf '%s\nmodel = "model.vamos"\n%s\n' "$profile_head" "$profile_tail" > "$assets/profile.toml"

"$vamos" calibrate --profile "$assets/profile.toml" "$work/sim/train" \
    --holdout "$work/sim/val" --alpha 0.1 > "$work/calibration.out"
# The same without the model, for a machine without ONNX Runtime (`vamos demo --no-model`).
{
    echo '# The demo profile without the flow predictor: what `vamos demo` runs when ONNX Runtime'
    echo '# is not available (or with --no-model). Its own calibration, on the same episodes.'
    printf '%s\n%s\n' "$profile_head" "$profile_tail" | sed 's/^name = "demo"$/name = "demo-no-model"/'
} > "$assets/profile-no-model.toml"
"$vamos" calibrate --profile "$assets/profile-no-model.toml" "$work/sim/train" \
    --holdout "$work/sim/val" --alpha 0.1 > "$work/calibration-no-model.out"
for f in "$work"/sim/test/*.mcap; do
    cp "$f" "${f%.mcap}.labels.json" "$assets/episodes/"
done

for old in robot camera.json model.vamos profile.toml profile.calibration.json \
    profile-no-model.toml profile-no-model.calibration.json episodes; do
    rm -rf "${here:?}/$old"
done
cp -r "$assets"/* "$here/"
du -sh "$here"
