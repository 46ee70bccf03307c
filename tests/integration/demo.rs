//! `vamos demo` end to end: the embedded assets, the in-process server, the bundled
//! episodes streamed as concurrent robots over gRPC, the report.

use serde_json::Value;
use std::process::Command;

#[test]
fn the_demo_streams_the_bundled_episodes_and_writes_its_report() {
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("demo");
    let out = Command::new(env!("CARGO_BIN_EXE_vamos"))
        .args(["demo", "--quiet", "--out"])
        .arg(&out_dir)
        .env("VAMOS_LOG__LEVEL", "warn")
        .env_remove("VAMOS_ADMIN_TOKEN")
        .env_remove("VAMOS_ROBOT_TOKEN")
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "demo failed:\n{stdout}\n{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    let report_md = out_dir.join("report.md");
    assert!(
        stdout.contains(&format!("report: {}", report_md.display())),
        "{stdout}"
    );

    let report: Value =
        serde_json::from_str(&std::fs::read_to_string(out_dir.join("report.json")).unwrap())
            .unwrap();
    let episodes = report["episodes"].as_array().unwrap();
    let bundled = std::fs::read_dir(out_dir.join("assets/episodes"))
        .unwrap()
        .filter(|e| {
            e.as_ref()
                .unwrap()
                .path()
                .extension()
                .is_some_and(|x| x == "mcap")
        })
        .count();
    assert!(bundled >= 5, "only {bundled} bundled episodes");
    assert_eq!(episodes.len(), bundled);
    // Every image sent was scored: the window pacing keeps the queue from dropping.
    let sent = report["images_sent"].as_u64().unwrap();
    assert!(sent > 100);
    assert_eq!(report["frames_scored"].as_u64().unwrap(), sent);
    assert_eq!(report["frames_dropped"].as_u64().unwrap(), 0);
    assert_eq!(report["message_errors"].as_u64().unwrap(), 0);
    // Both classes are present, so the frame-level AUCs exist and the plots were drawn.
    let eval = &report["evaluation"];
    let auc = eval["auc_roc"].as_f64().unwrap();
    assert!((0.0..=1.0).contains(&auc), "{eval}");
    assert!(eval["anomalous_episodes"].as_u64().unwrap() >= 3);
    assert!(report["alarm_threshold"].as_f64().unwrap().is_finite());
    for e in episodes {
        let name = e["episode"].as_str().unwrap();
        assert!(
            out_dir.join(format!("plots/{name}.png")).is_file(),
            "{name}"
        );
    }
    for plot in ["roc.png", "pr.png", "roc_per_type.png"] {
        let bytes = std::fs::read(out_dir.join("plots").join(plot)).unwrap();
        assert!(bytes.starts_with(b"\x89PNG"), "{plot}");
    }
    let md = std::fs::read_to_string(&report_md).unwrap();
    assert!(md.contains("| frame-level AUC-ROC |"), "{md}");
    assert!(md.contains("![ROC](plots/roc.png)"));
    assert!(
        md.contains("![ROC per type](plots/roc_per_type.png)"),
        "{md}"
    );

    // A second run reuses the unpacked assets and gives the same scores (the pipeline
    // is deterministic for a given session).
    let again = Command::new(env!("CARGO_BIN_EXE_vamos"))
        .args(["demo", "--quiet", "--robots", "2", "--out"])
        .arg(&out_dir)
        .env("VAMOS_LOG__LEVEL", "warn")
        .output()
        .unwrap();
    assert!(again.status.success());
    let second: Value =
        serde_json::from_str(&std::fs::read_to_string(out_dir.join("report.json")).unwrap())
            .unwrap();
    assert_eq!(
        second["evaluation"]["auc_roc"],
        report["evaluation"]["auc_roc"]
    );
    assert_eq!(second["episodes"], report["episodes"]);
}
