//! `vamos score`, `vamos calibrate` and `vamos eval` end to end on simulated episodes
//! (tests/fixtures/sim, made by `vamos-sim`; see make_fixture.sh): the robot from its
//! URDF, the camera from camera.json, the real MCAP bags with labels.

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

#[test]
fn score_calibrate_eval_on_simulated_episodes() {
    let ws = workspace();
    let dir = ws.path();

    // 1. Uncalibrated scores of the training episodes: no thresholds, no alarms.
    let (stdout, _) = vamos(
        dir,
        &[
            "score",
            "--profile",
            "profile.toml",
            "train",
            "-o",
            "train_scores",
        ],
    );
    let summaries: Vec<Value> = stdout
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(summaries.len(), 2);
    let mut train_frames = Vec::new();
    for s in &summaries {
        assert_eq!(s["alarms"], 0);
        assert_eq!(s["no_joint_states"], false);
        let frames = jsonl(&dir.join(format!(
            "train_scores/{}.scores.jsonl",
            s["episode"].as_str().unwrap()
        )));
        assert_eq!(frames.len() as u64, s["frames"].as_u64().unwrap());
        assert!(frames.len() > 20);
        // Every frame after the first has e_c and (the arm is in view) e_b.
        assert!(
            frames[1..]
                .iter()
                .all(|f| f["e_c"].is_f64() && f["e_b"].is_f64())
        );
        // No kinematic novelty before calibration: no nominal states yet.
        assert!(frames.iter().all(|f| f["e_k"].is_null()));
        train_frames.extend(frames);
    }

    // 2. Calibration: the e_c and e_b thresholds are the training maxima (checked against
    // the scores above); the conformal threshold from one held-out episode at alpha 0.5
    // is just above that episode's largest fused score.
    let (stdout, _) = vamos(
        dir,
        &[
            "calibrate",
            "--profile",
            "profile.toml",
            "train",
            "--holdout",
            "test/test_0000.mcap",
            "--alpha",
            "0.5",
        ],
    );
    let cal: Value = serde_json::from_str(&stdout).unwrap();
    let e_c = cal["thresholds"]["e_c"].as_f64().unwrap();
    let e_b = cal["thresholds"]["e_b"].as_f64().unwrap();
    assert_eq!(e_c, max_of(&train_frames, "e_c"));
    assert_eq!(e_b, max_of(&train_frames, "e_b"));
    assert_eq!(
        cal["training_frames"].as_u64().unwrap(),
        train_frames.len() as u64
    );
    let saved: Value = serde_json::from_str(
        &std::fs::read_to_string(dir.join("profile.calibration.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(saved, cal);
    // The kinematic novelty's nominal states: the training frames' joint positions and
    // velocities (10 joints), each scaled by its nominal range; e_k's scale from each
    // training frame against the other episode.
    let states = &cal["thresholds"]["kinematics"];
    assert_eq!(states["dims"], 20);
    let kept = states["count"].as_u64().unwrap();
    assert!(kept > 20 && kept < train_frames.len() as u64, "{kept}");
    assert_eq!(states["scale"].as_array().unwrap().len(), 20);
    assert!(
        cal["thresholds"]["scales"]["e_k"]["spread"]
            .as_f64()
            .unwrap()
            > 0.0
    );
    let conformal = &cal["conformal"];
    assert_eq!(conformal["n"], 1);
    assert_eq!(conformal["rank_k"], 1);

    // 3. Calibrated scores of the nominal held-out episode, with a scored bag.
    let (stdout, _) = vamos(
        dir,
        &[
            "score",
            "--profile",
            "profile.toml",
            "test/test_0000.mcap",
            "-o",
            "out",
            "--mcap",
        ],
    );
    let summary: Value = serde_json::from_str(stdout.trim()).unwrap();
    let nominal = jsonl(&dir.join("out/test_0000.scores.jsonl"));
    let nominal_max = max_of(&nominal, "score");
    assert_eq!(conformal["order_statistic"].as_f64().unwrap(), nominal_max);
    // Calibrated: every frame after the first (velocities need two) has e_k.
    assert!(nominal[0]["e_k"].is_null());
    assert!(nominal[1..].iter().all(|f| f["e_k"].is_f64()));
    assert!(max_of(&nominal[1..], "e_k") > 0.0);
    // A training episode's states are the nominal states (each within the thinning
    // spacing, 0.002, of one kept): scored again, its e_k stays below that.
    let first = summaries[0]["episode"].as_str().unwrap();
    vamos(
        dir,
        &[
            "score",
            "--profile",
            "profile.toml",
            &format!("train/{first}.mcap"),
            "-o",
            "train_again",
        ],
    );
    let again = jsonl(&dir.join(format!("train_again/{first}.scores.jsonl")));
    let e_k = max_of(&again[1..], "e_k");
    assert!((0.0..0.0021).contains(&e_k), "{e_k}");
    assert!(conformal["threshold"].as_f64().unwrap() > nominal_max);
    // The scene statistics were fitted on maps taken with the photometric check (the
    // default) and say so; a calibration made before the check (no such field) scores
    // its maps without it, whatever the profile says: other e_r, the same e_k.
    assert_eq!(cal["thresholds"]["scene"]["photometric"], true);
    let mut older = cal.clone();
    older["thresholds"]["scene"]
        .as_object_mut()
        .unwrap()
        .remove("photometric");
    let cal_path = dir.join("profile.calibration.json");
    std::fs::write(&cal_path, serde_json::to_vec(&older).unwrap()).unwrap();
    vamos(
        dir,
        &[
            "score",
            "--profile",
            "profile.toml",
            "test/test_0000.mcap",
            "-o",
            "older",
        ],
    );
    std::fs::write(&cal_path, serde_json::to_vec(&cal).unwrap()).unwrap();
    let older = jsonl(&dir.join("older/test_0000.scores.jsonl"));
    assert_eq!(older.len(), nominal.len());
    let field = |frames: &[Value], key: &str| -> Vec<Value> {
        frames.iter().map(|f| f[key].clone()).collect()
    };
    assert_eq!(field(&older, "e_k"), field(&nominal, "e_k"));
    let (e_r_now, e_r_before) = (max_of(&nominal, "e_r"), max_of(&older, "e_r"));
    assert!(
        e_r_now > 0.0 && e_r_before > 0.0 && e_r_now != e_r_before,
        "{e_r_now} {e_r_before}"
    );
    // The scored bag: the input images and one score per frame, readable by the reader.
    let bag = McapEpisode::open(
        &dir.join("out/test_0000.scored.mcap"),
        &EpisodeConfig::default(),
    )
    .unwrap();
    let info = bag.info();
    let count = |topic: &str| {
        info.topics
            .iter()
            .find(|t| t.name == topic)
            .map_or(0, |t| t.message_count)
    };
    assert_eq!(count("/vamos/score"), summary["frames"].as_u64().unwrap());
    assert_eq!(count("/vamos/anomaly"), count("/vamos/score"));
    assert_eq!(count("/vamos/e_k"), count("/vamos/score") - 1);
    assert_eq!(count("/camera/image_raw"), count("/vamos/score"));

    // 4. Evaluation on the labelled test episodes.
    let (stdout, _) = vamos(
        dir,
        &[
            "eval",
            "--profile",
            "profile.toml",
            "--episodes",
            "test",
            "--json",
            "report.json",
            "--plots",
            "plots",
        ],
    );
    let report: Value = serde_json::from_str(&stdout).unwrap();
    let file: Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("report.json")).unwrap()).unwrap();
    assert_eq!(report, file);
    for key in [
        "auc_roc",
        "auc_pr",
        "frames",
        "anomalous_frames",
        "episode_false_alarm_rate",
        "median_detection_delay_s",
        "timely_detection_rate",
        "per_type",
    ] {
        assert!(report.get(key).is_some(), "report lacks {key}");
    }
    // Frame counts, checked against the labels and the per-frame stamps.
    let (stdout, _) = vamos(
        dir,
        &[
            "score",
            "--profile",
            "profile.toml",
            "test",
            "-o",
            "test_scores",
        ],
    );
    let mut frames = 0;
    let mut anomalous = 0;
    for line in stdout.lines() {
        let s: Value = serde_json::from_str(line).unwrap();
        let name = s["episode"].as_str().unwrap();
        let labels = Labels::load_for(&dir.join(format!("test/{name}.mcap")))
            .unwrap()
            .unwrap();
        for f in jsonl(&dir.join(format!("test_scores/{name}.scores.jsonl"))) {
            frames += 1;
            if labels.is_anomalous(f["stamp_ns"].as_i64().unwrap()) {
                anomalous += 1;
            }
        }
    }
    assert_eq!(report["frames"], frames);
    assert_eq!(report["anomalous_frames"], anomalous);
    assert!(anomalous > 5);
    // The push shakes the camera while the joint states stay calm: the camera detector
    // finds it and ranks its frames high.
    let push = &report["per_type"]["external_push"];
    assert_eq!(push["detection_rate"], 1.0);
    assert!(push["auc_roc"].as_f64().unwrap() > 0.8, "{push}");
    for png in [
        "roc.png",
        "pr.png",
        "roc_per_type.png",
        "test_0001_external_push.png",
        "test_0001_external_push.detectors.png",
    ] {
        let img = image::open(dir.join("plots").join(png)).unwrap();
        assert!(img.width() >= 64 && img.height() >= 64);
    }
}

#[test]
fn bad_profiles_and_missing_labels_are_clear_errors() {
    let ws = workspace();
    let dir = ws.path();
    let run = |args: &[&str]| {
        let out = Command::new(env!("CARGO_BIN_EXE_vamos"))
            .current_dir(dir)
            .args(args)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
        assert!(!out.status.success());
        assert!(!stderr.contains("panicked"), "{stderr}");
        stderr
    };
    std::fs::write(
        dir.join("bad.toml"),
        "name = \"x\"\nrobot = \"robot/vamos_arm.urdf\"\n",
    )
    .unwrap();
    let e = run(&["score", "--profile", "bad.toml", "test"]);
    assert!(e.contains("no camera"), "{e}");
    std::fs::write(dir.join("typo.toml"), "name = \"x\"\nmodle = \"m.vamos\"\n").unwrap();
    let e = run(&["score", "--profile", "typo.toml", "test"]);
    assert!(e.contains("modle"), "{e}");
    // Episodes without labels cannot be evaluated.
    std::fs::remove_file(dir.join("test/test_0000.labels.json")).unwrap();
    let e = run(&[
        "eval",
        "--profile",
        "profile.toml",
        "--episodes",
        "test/test_0000.mcap",
    ]);
    assert!(e.contains("no labels"), "{e}");
    let e = run(&[
        "score",
        "--profile",
        "profile.toml",
        "empty_dir_does_not_exist.mcap",
    ]);
    assert!(e.contains("empty_dir_does_not_exist"), "{e}");
    let e = run(&["score", "--profile", "profile.toml", "test", "--mcap"]);
    assert!(e.contains("--out"), "{e}");
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

/// `vamos eval --ablation` end to end: one row per flow variant in the paper's order; the
/// variants given a model (`--variant-model`) are scored with it and show AUC pairs in
/// [0, 1] beside the paper's; the others are kept and marked "no model".
#[test]
fn eval_ablation_writes_a_row_per_variant() {
    let ws = workspace();
    let dir = ws.path();
    write_calibration(dir, "profile", 0.5, 0.5, 2e6, None);
    let model = tiny_model();
    let (stdout, stderr) = vamos(
        dir,
        &[
            "eval",
            "--profile",
            "profile.toml",
            "--episodes",
            "test",
            "--ablation",
            "ablation.md",
            "--variant-model",
            &format!("masked={model}"),
            "--variant-model",
            &format!("plain={model}"),
            "--no-progress",
        ],
    );
    let report: Value = serde_json::from_str(&stdout).unwrap();
    assert!(report["anomalous_frames"].as_u64().unwrap() > 0);
    let md = std::fs::read_to_string(dir.join("ablation.md")).unwrap();
    let lines: Vec<&str> = md.lines().collect();
    assert_eq!(lines.len(), 6, "{md}");
    assert_eq!(
        cells(lines[0]),
        [
            "input flow variant",
            "OF only",
            "OF + body",
            "OF + body + camera"
        ]
    );
    assert_eq!(lines[1], "|---|---|---|---|");
    let rows: Vec<Vec<String>> = lines[2..].iter().map(|l| cells(l)).collect();
    assert_eq!(
        rows.iter().map(|r| r[0].as_str()).collect::<Vec<_>>(),
        ["plain", "registered", "masked", "masked + registered"]
    );
    for row in &rows {
        assert_eq!(row.len(), 4, "{row:?}");
    }
    for row in [&rows[0], &rows[2]] {
        for cell in &row[1..] {
            // "0.612 / 0.345 (paper 0.740 / 0.380)"
            let (ours, paper) = cell
                .split_once(" (paper ")
                .unwrap_or_else(|| panic!("{cell}"));
            assert!(paper.ends_with(')'), "{cell}");
            let (roc, pr) = ours.split_once(" / ").unwrap_or_else(|| panic!("{cell}"));
            for v in [roc, pr] {
                let v: f64 = v.parse().unwrap_or_else(|_| panic!("{cell}"));
                assert!((0.0..=1.0).contains(&v), "{cell}");
            }
        }
    }
    for row in [&rows[1], &rows[3]] {
        for cell in &row[1..] {
            assert!(cell.starts_with("no model (paper "), "{row:?}");
        }
    }
    assert!(
        stderr.contains("no model for flow variant registered"),
        "{stderr}"
    );
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

/// `vamos score --mcap` with a model: the scored bag holds the images, /vamos/score and
/// /vamos/anomaly for every frame, /vamos/e_c, /vamos/e_b and /vamos/e_o for every frame
/// that has them (Float64, the values of the JSON lines) and one /vamos/heatmap (a 64x64
/// rgb8 Image) per frame with e_o.
#[test]
fn score_mcap_with_a_model_writes_every_score_topic() {
    let ws = workspace();
    let dir = ws.path();
    write_model_profile(dir, "model");
    let (stdout, _) = vamos(
        dir,
        &[
            "score",
            "--profile",
            "model.toml",
            "test/test_0000.mcap",
            "-o",
            "out",
            "--mcap",
            "--no-progress",
        ],
    );
    let summary: Value = serde_json::from_str(stdout.trim()).unwrap();
    let frames = jsonl(&dir.join("out/test_0000.scores.jsonl"));
    let n = frames.len();
    assert_eq!(n as u64, summary["frames"].as_u64().unwrap());
    let values =
        |key: &str| -> Vec<f64> { frames.iter().filter_map(|f| f[key].as_f64()).collect() };
    let (e_c, e_b, e_o) = (values("e_c"), values("e_b"), values("e_o"));
    // Processed frame 0 has no flow, then A + B = 4 frames of history: e_o from frame 5.
    assert_eq!(e_o.len(), n - 5, "{n} frames");
    assert_eq!(e_c.len(), n - 1);
    assert!(!e_b.is_empty());

    let bag = McapEpisode::open(
        &dir.join("out/test_0000.scored.mcap"),
        &EpisodeConfig::default(),
    )
    .unwrap();
    let info = bag.info();
    let topic = |name: &str| info.topics.iter().find(|t| t.name == name).cloned();
    for (name, count, schema) in [
        ("/camera/image_raw", n, "sensor_msgs/msg/Image"),
        ("/vamos/score", n, "std_msgs/msg/Float64"),
        ("/vamos/anomaly", n, "std_msgs/msg/Bool"),
        ("/vamos/e_c", e_c.len(), "std_msgs/msg/Float64"),
        ("/vamos/e_b", e_b.len(), "std_msgs/msg/Float64"),
        ("/vamos/e_o", e_o.len(), "std_msgs/msg/Float64"),
        ("/vamos/heatmap", e_o.len(), "sensor_msgs/msg/Image"),
    ] {
        let t = topic(name).unwrap_or_else(|| panic!("no {name} in {:?}", info.topics));
        assert_eq!(
            (t.message_count, t.schema.as_str()),
            (count as u64, schema),
            "{name}"
        );
    }
    let (mut got_e_c, mut got_e_b, mut got_e_o, mut maps) = (vec![], vec![], vec![], 0);
    bag.for_each_message(
        &[
            "/vamos/e_c".into(),
            "/vamos/e_b".into(),
            "/vamos/e_o".into(),
            "/vamos/heatmap".into(),
        ],
        |topic, _, _, cdr| match topic {
            "/vamos/heatmap" => {
                let m = ImageMsg::decode(cdr).unwrap();
                assert_eq!((m.width, m.height, m.encoding.as_str()), (64, 64, "rgb8"));
                maps += 1;
            }
            "/vamos/e_c" => got_e_c.push(decode_f64(cdr).unwrap()),
            "/vamos/e_b" => got_e_b.push(decode_f64(cdr).unwrap()),
            _ => got_e_o.push(decode_f64(cdr).unwrap()),
        },
    )
    .unwrap();
    assert_eq!((got_e_c, got_e_b, got_e_o), (e_c, e_b, e_o.clone()));
    assert_eq!(maps, e_o.len());
}

/// The alarm rule picks the threshold on the fused score: `alarm = "conformal"` the stored
/// conformal threshold, `alarm = "max"` the next float above the training maximum. The two
/// thresholds are put between this episode's own scores so that they flag different frames.
#[test]
fn the_alarm_rule_picks_the_conformal_or_the_max_threshold() {
    let ws = workspace();
    let dir = ws.path();
    std::fs::write(
        dir.join("conformal.toml"),
        PROFILE.replacen("alarm = \"max\"", "alarm = \"conformal\"", 1),
    )
    .unwrap();
    let score = |profile: &str| {
        let out = format!("out_{profile}");
        let (stdout, _) = vamos(
            dir,
            &[
                "score",
                "--profile",
                &format!("{profile}.toml"),
                "test/test_0001_external_push.mcap",
                "-o",
                &out,
                "--no-progress",
            ],
        );
        let summary: Value = serde_json::from_str(stdout.trim()).unwrap();
        let frames = jsonl(&dir.join(format!("{out}/test_0001_external_push.scores.jsonl")));
        (summary, frames)
    };
    // Small e_c/e_b thresholds: most frames trigger, their fused scores 1e6 + e / e_thres
    // differ. No alarm yet (the max rule with a huge training maximum).
    write_calibration(dir, "profile", 0.2, 0.2, 1e300, None);
    let (_, frames) = score("profile");
    assert!(frames.iter().all(|f| f["anomaly"] == false));
    let mut scores: Vec<f64> = frames
        .iter()
        .map(|f| f["score"].as_f64().unwrap())
        .collect();
    scores.sort_by(f64::total_cmp);
    scores.dedup();
    assert!(scores.len() >= 6, "{scores:?}");
    let (conformal, max) = (scores[scores.len() / 3], scores[2 * scores.len() / 3]);
    for stem in ["profile", "conformal"] {
        write_calibration(dir, stem, 0.2, 0.2, max, Some(conformal));
    }
    let mut alarms = Vec::new();
    for (profile, threshold) in [("conformal", conformal), ("profile", max.next_up())] {
        let (summary, frames) = score(profile);
        let mut n = 0;
        for f in &frames {
            let s = f["score"].as_f64().unwrap();
            assert_eq!(f["anomaly"], s >= threshold, "{profile}: {f}");
            n += usize::from(s >= threshold);
        }
        assert_eq!(summary["alarms"], n, "{profile}");
        assert!(n > 0, "{profile}");
        alarms.push(n);
    }
    assert!(
        alarms[0] > alarms[1],
        "conformal is the lower threshold here: {alarms:?}"
    );
}

/// A gap in the joint states is reported per episode: `vamos score`'s summary lists the
/// images whose nearest joint sample is beyond `[episode] max_joint_gap_ms` (100 ms) —
/// those of `joint_gap.mcap` that `make_bags.py` computed — and none for a bag without gap.
#[test]
fn joint_gaps_are_listed_in_the_score_summary() {
    let episodes = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/episode");
    let expected: Value =
        serde_json::from_str(&std::fs::read_to_string(episodes.join("expected.json")).unwrap())
            .unwrap();
    let bag = expected["bags"]
        .as_array()
        .unwrap()
        .iter()
        .find(|b| b["file"] == "joint_gap.mcap")
        .unwrap();
    let want: Vec<u64> = bag["gap_frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_u64().unwrap())
        .collect();
    assert!(!want.is_empty());
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("p.toml"),
        "name = \"p\"\nflow_preset = \"realtime\"\n[pipeline]\nstride = 1\n\
         [pipeline.frames]\nwidth = 64\nheight = 48\nvariant = \"plain\"\n",
    )
    .unwrap();
    let (stdout, _) = vamos(
        dir.path(),
        &[
            "score",
            "--profile",
            "p.toml",
            &episodes.join("joint_gap.mcap").display().to_string(),
            &episodes.join("interleaved.mcap").display().to_string(),
            "--no-progress",
        ],
    );
    let summaries: Vec<Value> = stdout
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let gaps = &summaries[0]["joint_gaps"];
    assert_eq!(summaries[0]["episode"], "joint_gap");
    let got: Vec<u64> = gaps
        .as_array()
        .unwrap()
        .iter()
        .map(|g| g["index"].as_u64().unwrap())
        .collect();
    assert_eq!(got, want, "{gaps}");
    let frames = bag["frames"].as_array().unwrap();
    for g in gaps.as_array().unwrap() {
        let f = frames.iter().find(|f| f["index"] == g["index"]).unwrap();
        assert_eq!(g["stamp_ns"], f["stamp_ns"]);
        let gap_ms = f["joints"]["gap_ns"].as_f64().unwrap() * 1e-6;
        assert!((g["gap_ms"].as_f64().unwrap() - gap_ms).abs() < 1e-9, "{g}");
        assert!(gap_ms > 100.0);
    }
    assert_eq!(summaries[1]["episode"], "interleaved");
    assert_eq!(summaries[1]["joint_gaps"], serde_json::json!([]));
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

/// A bag without joint states, scored with a robot and a model: `no_joint_states`, no
/// `e_c` or `e_b` on any frame, `e_o` after the model's warm-up and the score is `e_o`.
#[test]
fn a_bag_without_joint_states_is_scored_from_e_o() {
    let ws = workspace();
    let dir = ws.path();
    write_model_profile(dir, "model");
    std::fs::create_dir(dir.join("nojoints")).unwrap();
    copy_topics(
        &dir.join("test/test_0000.mcap"),
        &dir.join("nojoints/test_0000.mcap"),
        &["/camera/image_raw", "/camera/camera_info"],
    );
    let (stdout, _) = vamos(
        dir,
        &[
            "score",
            "--profile",
            "model.toml",
            "nojoints/test_0000.mcap",
            "-o",
            "out",
            "--no-progress",
        ],
    );
    let summary: Value = serde_json::from_str(stdout.trim()).unwrap();
    assert_eq!(summary["no_joint_states"], true);
    assert_eq!(summary["refused"], serde_json::json!([]));
    let frames = jsonl(&dir.join("out/test_0000.scores.jsonl"));
    assert_eq!(frames.len(), 30);
    assert!(
        frames
            .iter()
            .all(|f| f["e_c"].is_null() && f["e_b"].is_null())
    );
    let with_e_o: Vec<&Value> = frames.iter().filter(|f| f["e_o"].is_f64()).collect();
    assert_eq!(with_e_o.len(), frames.len() - 5);
    for f in with_e_o {
        assert!(f["e_o"].as_f64().unwrap() > 0.0);
        assert_eq!(f["score"], f["e_o"], "nothing triggers without e_c/e_b");
    }
}

/// A bag without CameraInfo takes the profile camera's intrinsics: `e_c` and `e_b` are
/// computed and equal those of the same bag with its CameraInfo (which carries the same K
/// as the fixture's camera.json).
#[test]
fn a_bag_without_camera_info_uses_the_profile_intrinsics() {
    let ws = workspace();
    let dir = ws.path();
    std::fs::create_dir(dir.join("nocam")).unwrap();
    copy_topics(
        &dir.join("test/test_0000.mcap"),
        &dir.join("nocam/test_0000.mcap"),
        &["/camera/image_raw", "/joint_states"],
    );
    let nocam =
        McapEpisode::open(&dir.join("nocam/test_0000.mcap"), &EpisodeConfig::default()).unwrap();
    assert_eq!(nocam.info().chosen.camera_info, None);
    let run = |bag: &str, out: &str| {
        vamos(
            dir,
            &[
                "score",
                "--profile",
                "profile.toml",
                bag,
                "-o",
                out,
                "--no-progress",
            ],
        );
        jsonl(&dir.join(format!("{out}/test_0000.scores.jsonl")))
    };
    let without = run("nocam/test_0000.mcap", "out_nocam");
    let with = run("test/test_0000.mcap", "out_cam");
    assert_eq!(without.len(), 30);
    assert!(
        without[1..]
            .iter()
            .all(|f| f["e_c"].is_f64() && f["e_b"].is_f64())
    );
    for (a, b) in without.iter().zip(&with) {
        for key in ["e_c", "e_b", "score"] {
            assert_eq!(a[key], b[key], "frame {}: {key}", a["index"]);
        }
    }
}
