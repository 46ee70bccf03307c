//! The store's unit tests, by subject; the helpers below are shared.

mod durability;
mod mirror;
mod models;
mod profiles;
mod robots;

use super::*;
use serde_json::json;
use std::collections::HashMap;
use std::path::Path;
use vamos_core::eval::{ConformalThreshold, Thresholds};
use vamos_core::pipeline::AlarmRule;
use vamos_model::bundle::sha256_hex;
use vamos_robot::{CameraSpec, Robot, RobotConfig};

fn fixture(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/fixtures")
        .join(rel)
}

fn open(dir: &Path) -> Store {
    Store::open(dir, StoreLimits::default()).unwrap()
}

/// Uploads `bytes` in chunks of 7 bytes.
fn upload(store: &Store, kind: UploadKind, bytes: &[u8]) -> Upload {
    let mut u = store.begin_upload(kind).unwrap();
    for chunk in bytes.chunks(7) {
        u.write_chunk(chunk).unwrap();
    }
    assert_eq!(u.bytes(), bytes.len() as u64);
    u
}

fn accept(v: serde_json::Value) -> impl FnOnce(&Path) -> Result<serde_json::Value, String> {
    move |_| Ok(v)
}

fn commit_model(store: &Store, name: &str, bytes: &[u8]) -> ModelVersionInfo {
    let u = upload(store, UploadKind::Model, bytes);
    store
        .commit_model(name, u, accept(json!({"len": bytes.len()})))
        .unwrap()
}

fn commit_urdf(store: &Store, name: &str) -> RobotInfo {
    let bytes = std::fs::read(fixture("sim/robot/vamos_arm.urdf")).unwrap();
    let u = upload(
        store,
        UploadKind::Robot {
            format: RobotFormat::Urdf,
        },
        &bytes,
    );
    store
        .commit_robot(name, u, |p| robot_summary(p, &RobotConfig::default()))
        .unwrap()
}

fn camera() -> CameraSpec {
    serde_json::from_str(&std::fs::read_to_string(fixture("sim/camera.json")).unwrap()).unwrap()
}

fn calibration(model_sha256: Option<String>) -> Calibration {
    Calibration {
        created_unix_s: 42,
        model_sha256,
        training_episodes: vec!["a".into(), "b".into()],
        calibration_episodes: vec!["c".into()],
        training_frames: 120,
        thresholds: Thresholds::paper(Some(1.5), Some(3.25)),
        score_max: 0.5,
        conformal: Some(ConformalThreshold {
            threshold: 0.75,
            order_statistic: 0.75f64.next_down(),
            alpha: 0.1,
            n: 19,
            rank_k: 18,
            guaranteed_false_alarm_max: 0.1,
            marginal_false_alarm_bound: 0.1,
            confidence: 0.6,
            calibration_false_alarm_rate: 0.0,
            episode_maxima: Vec::new(),
        }),
    }
}

fn entries(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}
