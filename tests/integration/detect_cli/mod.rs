//! `vamos score`, `vamos calibrate` and `vamos eval` end to end on simulated episodes
//! (tests/fixtures/sim, made by `vamos-sim`; see make_fixture.sh): the robot from its
//! URDF, the camera from camera.json, the real MCAP bags with labels.

mod calibrate;
mod inputs;
mod layout;
mod model;

use serde_json::Value;

use std::path::{Path, PathBuf};

use std::process::Command;

use vamos::episode::ros::{ImageMsg, decode_f64};

use vamos::episode::{EpisodeConfig, Labels, McapEpisode, ScoreBagWriter};

const PROFILE: &str = r#"name = "sim-arm"
robot = "robot/vamos_arm.urdf"
camera = "camera.json"
flow_preset = "realtime"
alarm = "max"
[pipeline]
stride = 1
# These tests pin the paper's fusion (its triggered band); the no-model default is
# the calibrated fusion.
fusion = "paper"
[pipeline.frames]
width = 160
height = 120
variant = "masked"
"#;

fn fixture() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/sim")
}

/// The fixture copied into a temporary folder (calibration is written beside the profile).
fn workspace() -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    copy_dir(&fixture(), dir.path());
    std::fs::write(dir.path().join("profile.toml"), PROFILE).unwrap();
    dir
}

fn copy_dir(from: &Path, to: &Path) {
    for entry in std::fs::read_dir(from).unwrap() {
        let entry = entry.unwrap();
        let target = to.join(entry.file_name());
        if entry.file_type().unwrap().is_dir() {
            std::fs::create_dir_all(&target).unwrap();
            copy_dir(&entry.path(), &target);
        } else {
            std::fs::copy(entry.path(), target).unwrap();
        }
    }
}

fn vamos(dir: &Path, args: &[&str]) -> (String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_vamos"))
        .current_dir(dir)
        .args(args)
        .env("VAMOS_LOG__LEVEL", "warn")
        .output()
        .unwrap();
    let (stdout, stderr) = (
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    );
    assert!(out.status.success(), "vamos {args:?} failed:\n{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    (stdout, stderr)
}

fn jsonl(path: &Path) -> Vec<Value> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

fn max_of(frames: &[Value], key: &str) -> f64 {
    frames
        .iter()
        .filter_map(|f| f[key].as_f64())
        .fold(f64::NEG_INFINITY, f64::max)
}

/// The committed tiny model bundle (A = 2, B = 2, M = 3; trained on the masked variant).
fn tiny_model() -> String {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/model/valid.vamos")
        .display()
        .to_string()
}

/// Writes `<stem>.calibration.json` in `dir`, as `vamos calibrate` would for the profile
/// `<stem>.toml`: `e_c`/`e_b` thresholds, the training maximum of the fused score and,
/// when given, a conformal threshold.
fn write_calibration(dir: &Path, stem: &str, e_c: f64, e_b: f64, max: f64, conformal: Option<f64>) {
    let conformal = conformal.map(|t| {
        serde_json::json!({
            "threshold": t, "order_statistic": t, "alpha": 0.1, "n": 9, "rank_k": 9,
            "guaranteed_false_alarm_max": 0.1, "marginal_false_alarm_bound": 0.1,
            "confidence": 0.61, "calibration_false_alarm_rate": 0.0,
        })
    });
    let cal = serde_json::json!({
        "created_unix_s": 1, "model_sha256": null, "training_episodes": ["train_0000"],
        "calibration_episodes": [], "training_frames": 30,
        "thresholds": {"e_c": e_c, "e_b": e_b}, "score_max": max, "conformal": conformal,
    });
    std::fs::write(
        dir.join(format!("{stem}.calibration.json")),
        cal.to_string(),
    )
    .unwrap();
}

/// The cells of a markdown table row.
fn cells(line: &str) -> Vec<String> {
    line.trim()
        .trim_matches('|')
        .split('|')
        .map(|c| c.trim().to_string())
        .collect()
}

/// The profile of [`PROFILE`] with the tiny model, as `<stem>.toml` in `dir`.
fn write_model_profile(dir: &Path, stem: &str) {
    let text = PROFILE.replacen(
        "alarm = \"max\"\n",
        &format!("alarm = \"max\"\nmodel = {:?}\n", tiny_model()),
        1,
    );
    std::fs::write(dir.join(format!("{stem}.toml")), text).unwrap();
}

/// Copies the bag `src` to `dst` keeping only `topics` (schemas and messages unchanged).
fn copy_topics(src: &Path, dst: &Path, topics: &[&str]) {
    let ep = McapEpisode::open(src, &EpisodeConfig::default()).unwrap();
    let schemas: std::collections::HashMap<String, (String, String, Vec<u8>)> = topics
        .iter()
        .map(|t| (t.to_string(), ep.schema_of(t).unwrap().unwrap()))
        .collect();
    let mut w = ScoreBagWriter::create(dst, None).unwrap();
    let mut written = Ok(());
    let topics: Vec<String> = topics.iter().map(|t| t.to_string()).collect();
    ep.for_each_message(&topics, |topic, _, log_time, cdr| {
        let (name, encoding, data) = &schemas[topic];
        if written.is_ok() {
            written = w.copy_message(topic, name, encoding, data, cdr, log_time);
        }
    })
    .unwrap();
    written.unwrap();
    w.finish().unwrap();
}
