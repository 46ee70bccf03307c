//! score, calibrate and eval end to end; bad profiles; the alarm rule.

use super::*;

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
