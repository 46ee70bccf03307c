#!/bin/sh
# The detectors beyond the paper, without a flow predictor (docs/detection-history.md):
# calibrate and evaluate one profile per row of the table on a simulated dataset made by
# scripts/benchmark.sh (or `vamos-sim generate --seed 7 --width 320 --height 240`).
#
#   scripts/detectors.sh SIM_DIR OUT_DIR [ROW...]
#
# Rows: paper, all, all_quantile, scene_camera, scene, scene_phase, all_phase,
# scene_phase_w3 (each without the kinematic novelty e_k), kinematics (e_k alone),
# scene_kinematics, scene_phase_kinematics_w3, all_kinematics_positions (velocity_s = 0),
# all_kinematics_links (state = "links"), all_kinematics_w3, all_phase_kinematics_w3,
# no_photometric (the default without the scene residual's photometric check), default (a
# profile that sets nothing: what a user gets; default: all), and with a flow predictor:
# calibrated (every detector, calibrated fusion), cells (the same with the localised e_o:
# flow_pooling = "cells"), cells_w3 (and temporal_window = 3), flow (e_o alone, calibrated),
# flow_m1 (the same with one prior sample per past offset instead of the bundle's M: what
# sampling buys); attach (the default with the carried book attached to the tool as a box of
# the simulator's mean book size), attach_while
# (the same, there only while the first finger joint reads below 3/4 of its opening: while the
# gripper is closed on the book), attach_while_w3 (and temporal_window = 3); effort (the
# default with the joints' efforts in e_k's state: [pipeline.kinematics] effort = true),
# attach_while_w3_effort (attach_while_w3 with them); learn_depth (the default with the
# static scene's depth learned at calibration: [pipeline.camera_motion] learn_depth = true),
# attach_while_learn_depth (attach_while with it). Each row leaves
# OUT_DIR/ROW/{profile.toml, profile.calibration.json, eval.json} and prints one line.
# MODEL=PATH (a model bundle trained on SIM_DIR's training episodes, e.g. by
# scripts/benchmark.sh) gives every row the flow predictor. DEPTH_TOPIC=TOPIC (a dataset made
# with `vamos-sim generate --depth`: /camera/depth/image_raw) gives every row the recorded
# depth images for the expected motion of the static scene. ALPHA (default 0.2) is the
# conformal threshold's alpha: with n held-out nominal episodes it is their maximum unless
# n >= (2 - alpha) / alpha (9 at 0.2, 19 at 0.1).
# FLOW_PRESET (default realtime) is every row's TV-L1 preset (default, realtime,
# realtime-hq, balanced).
# Needs the release binary (cargo build --release); about 90 s per row on 2 cores without
# a model.
set -eu
sim=$(cd "${1:?usage: scripts/detectors.sh SIM_DIR OUT_DIR [ROW...]}" && pwd)
out=${2:?usage: scripts/detectors.sh SIM_DIR OUT_DIR [ROW...]}
shift 2
root=$(cd "$(dirname "$0")/.." && pwd)
vamos=${VAMOS:-"$root/target/release/vamos"}
rows=${*:-paper all all_quantile scene_camera scene scene_phase all_phase scene_phase_w3 kinematics scene_kinematics scene_phase_kinematics_w3 all_kinematics_positions all_kinematics_links all_kinematics_w3 all_phase_kinematics_w3 no_photometric default}
# The dataset's robot (vamos-sim writes one URDF into SIM_DIR/robot).
urdf=$(ls "$sim"/robot/*.urdf | head -n 1)
# The tool link and the finger joint of the simulator's two robots, and three quarters of
# the finger's opening: above any book it closes on, below open.
case $(basename "$urdf" .urdf) in
    vamos_panda) tool=panda_grasptarget finger=panda_finger_joint1 closed_below=0.03 ;;
    *) tool=tool_link finger=finger_left_joint closed_below=0.0375 ;;
esac
# ATTACH_BOX / ATTACH_XYZ replace the box's size and place (e.g. one that covers the
# simulator's largest book: [0.18, 0.05, 0.26] at [0.0, 0.0, 0.085]).
book="[[pipeline.attach]]
link = \"$tool\"
box = ${ATTACH_BOX:-[0.15, 0.035, 0.215]}
xyz = ${ATTACH_XYZ:-[0.0, 0.0, 0.07]}"
depth_lines=
if [ -n "${DEPTH_TOPIC:-}" ]; then
    depth_lines="[topics]
depth = \"$DEPTH_TOPIC\""
fi
model_line=
if [ -n "${MODEL:-}" ]; then
    model_line="model = \"$(cd "$(dirname "$MODEL")" && pwd)/$(basename "$MODEL")\""
fi
for row in $rows; do
    case $row in
        paper) extra='fusion = "paper"
[pipeline.detectors]
kinematics = false' ;;
        all) extra='fusion = "calibrated"
[pipeline.detectors]
kinematics = false' ;;
        all_quantile) extra='fusion = "calibrated"
[pipeline.detectors]
kinematics = false
[pipeline.residual]
body_error = "quantile"' ;;
        scene_camera) extra='fusion = "calibrated"
[pipeline.detectors]
body = false
kinematics = false' ;;
        scene) extra='fusion = "calibrated"
[pipeline.detectors]
camera = false
body = false
kinematics = false' ;;
        scene_phase) extra='fusion = "calibrated"
[pipeline.detectors]
camera = false
body = false
kinematics = false
[pipeline.residual]
phase_window_s = 1.0' ;;
        all_phase) extra='fusion = "calibrated"
[pipeline.detectors]
kinematics = false
[pipeline.residual]
phase_window_s = 1.0' ;;
        scene_phase_w3) extra='fusion = "calibrated"
temporal_window = 3
[pipeline.detectors]
camera = false
body = false
kinematics = false
[pipeline.residual]
phase_window_s = 1.0' ;;
        kinematics) extra='fusion = "calibrated"
[pipeline.detectors]
camera = false
body = false
scene = false' ;;
        scene_kinematics) extra='fusion = "calibrated"
[pipeline.detectors]
camera = false
body = false' ;;
        scene_phase_kinematics_w3) extra='fusion = "calibrated"
temporal_window = 3
[pipeline.detectors]
camera = false
body = false
[pipeline.residual]
phase_window_s = 1.0' ;;
        all_kinematics_positions) extra='fusion = "calibrated"
[pipeline.kinematics]
velocity_s = 0.0' ;;
        all_phase_kinematics_w3) extra='fusion = "calibrated"
temporal_window = 3
[pipeline.residual]
phase_window_s = 1.0' ;;
        all_kinematics_w3) extra='fusion = "calibrated"
temporal_window = 3' ;;
        all_kinematics_links) extra='fusion = "calibrated"
[pipeline.kinematics]
state = "links"' ;;
        no_photometric) extra='[pipeline.residual]
photometric = false' ;;
        default) extra='' ;;
        calibrated) extra='fusion = "calibrated"' ;;
        attach) extra="$book" ;;
        attach_while) extra="$book
while = { joint = \"$finger\", below = $closed_below }" ;;
        attach_while_w3) extra="temporal_window = 3
$book
while = { joint = \"$finger\", below = $closed_below }" ;;
        effort) extra='[pipeline.kinematics]
effort = true' ;;
        attach_while_w3_effort) extra="temporal_window = 3
$book
while = { joint = \"$finger\", below = $closed_below }
[pipeline.kinematics]
effort = true" ;;
        learn_depth) extra='[pipeline.camera_motion]
learn_depth = true' ;;
        attach_while_learn_depth) extra="$book
while = { joint = \"$finger\", below = $closed_below }
[pipeline.camera_motion]
learn_depth = true" ;;
        cells) extra='fusion = "calibrated"
[pipeline.residual]
flow_pooling = "cells"' ;;
        cells_w3) extra='fusion = "calibrated"
temporal_window = 3
[pipeline.residual]
flow_pooling = "cells"' ;;
        flow) extra='fusion = "calibrated"
[pipeline.detectors]
camera = false
body = false
scene = false
kinematics = false' ;;
        flow_m1) extra='fusion = "calibrated"
samples = 1
[pipeline.detectors]
camera = false
body = false
scene = false
kinematics = false' ;;
        *) echo "unknown row $row" >&2; exit 2 ;;
    esac
    d="$out/$row"
    mkdir -p "$d"
    cat > "$d/profile.toml" <<TOML
name = "detectors-$row"
robot = "$urdf"
camera = "$sim/camera.json"
$model_line
flow_preset = "${FLOW_PRESET:-realtime}"
alarm = "conformal"
[pipeline]
stride = 1
$extra
[pipeline.frames]
width = 320
height = 240
variant = "masked"
$depth_lines
TOML
    "$vamos" calibrate --profile "$d/profile.toml" "$sim/train" --holdout "$sim/val" \
        --alpha "${ALPHA:-0.2}" --no-progress > "$d/calibration.out" 2> "$d/calibrate.log"
    "$vamos" eval --profile "$d/profile.toml" --episodes "$sim/test" --json "$d/eval.json" \
        --no-progress > /dev/null 2> "$d/eval.log"
    python3 - "$row" "$d/eval.json" <<'PY'
import json, sys
r = json.load(open(sys.argv[2]))
types = " ".join(f"{k}={v['auc_roc']:.2f}" for k, v in sorted(r["per_type"].items()))
print(f"{sys.argv[1]}: AUC-ROC {r['auc_roc']:.3f} AUC-PR {r['auc_pr']:.3f} "
      f"false-alarm episodes {r['episode_false_alarm_rate']:.2f} detected {r['detection_rate']:.2f} | {types}")
PY
done
