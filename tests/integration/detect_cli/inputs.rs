//! Bags that lack something: joint gaps, no joint states, no camera info.

use super::*;

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
