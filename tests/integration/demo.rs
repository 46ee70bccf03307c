//! `vamos demo` end to end: the embedded assets, the in-process server, the bundled
//! episodes streamed as concurrent robots over gRPC, the report.

use serde_json::Value;
use std::path::Path;
use std::process::Command;

/// `vamos demo ARGS --out OUT` with warnings only and no tokens from the caller's
/// environment (the demo's server makes its own).
fn demo_command(args: &[&str], out: &Path) -> Command {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_vamos"));
    cmd.arg("demo")
        .args(args)
        .arg("--out")
        .arg(out)
        .env("VAMOS_LOG__LEVEL", "warn")
        .env_remove("VAMOS_ADMIN_TOKEN")
        .env_remove("VAMOS_ROBOT_TOKEN")
        .env_remove("VAMOS_VIEWER_TOKEN");
    cmd
}

/// The run's `report.json`.
fn read_report(out: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap()
}

#[test]
fn the_demo_streams_the_bundled_episodes_and_writes_its_report() {
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("demo");
    let out = demo_command(&["--quiet"], &out_dir).output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "demo failed:\n{stdout}\n{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    let report_md = out_dir.join("report.md");
    assert!(
        stdout.contains(&format!("report: {}", report_md.display())),
        "{stdout}"
    );
    // The bundled model runs on ONNX Runtime: the run says which library and from where.
    let runtime = stdout
        .lines()
        .find_map(|l| l.strip_prefix("ONNX Runtime: "))
        .unwrap_or_else(|| panic!("no ONNX Runtime line: {stdout}"));
    assert!(
        runtime.contains("libonnxruntime") && runtime.contains("s to find and load"),
        "{runtime}"
    );

    let report = read_report(&out_dir);
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
    let md = std::fs::read_to_string(&report_md).unwrap();
    let mut alarmed = 0;
    for e in episodes {
        let name = e["episode"].as_str().unwrap();
        for plot in [format!("{name}.png"), format!("{name}.detectors.png")] {
            let bytes = std::fs::read(out_dir.join("plots").join(&plot)).unwrap();
            assert!(bytes.starts_with(b"\x89PNG"), "{plot}");
        }
        assert!(
            md.contains(&format!("(plots/{name}.detectors.png)")),
            "{name}"
        );
        // An episode with an alarm (debounced, so a flagged frame is needed) shows the
        // frame at its first alarm beside the same frame with its map (twice as wide).
        let frame = out_dir.join(format!("plots/{name}.first_alarm.png"));
        if e["first_alarm_ns"].is_null() {
            assert!(!frame.exists(), "{name}");
        } else if frame.exists() {
            alarmed += 1;
            let img = image::open(&frame).unwrap();
            assert!(
                img.width() == 2 * 160 && img.height() == 120,
                "{name}: {img:?}"
            );
            assert!(
                md.contains(&format!("(plots/{name}.first_alarm.png)")),
                "{name}"
            );
        }
    }
    assert!(alarmed >= 3, "{alarmed} episodes with an alarm");
    for plot in ["roc.png", "pr.png", "roc_per_type.png"] {
        let bytes = std::fs::read(out_dir.join("plots").join(plot)).unwrap();
        assert!(bytes.starts_with(b"\x89PNG"), "{plot}");
    }
    assert!(md.contains("| frame-level AUC-ROC |"), "{md}");
    assert!(md.contains("![ROC](plots/roc.png)"));
    assert!(
        md.contains("![ROC per type](plots/roc_per_type.png)"),
        "{md}"
    );

    // A second run reuses the unpacked assets and gives the same scores (the pipeline
    // is deterministic for a given session).
    let again = demo_command(&["--quiet", "--robots", "2"], &out_dir)
        .output()
        .unwrap();
    assert!(again.status.success());
    let second = read_report(&out_dir);
    assert_eq!(
        second["evaluation"]["auc_roc"],
        report["evaluation"]["auc_roc"]
    );
    assert_eq!(second["episodes"], report["episodes"]);
}

/// `vamos demo --serve`: after the demo the server and its page stay up, the robots keep
/// replaying, the URL is printed; Ctrl-C (SIGINT) stops it cleanly.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn demo_serve_keeps_the_page_and_the_robots_up_until_interrupted() {
    use std::io::{BufRead, BufReader};
    /// Stops the server whatever happens to the test.
    struct Running(std::process::Child);
    impl Drop for Running {
        fn drop(&mut self) {
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }
    let dir = tempfile::tempdir().unwrap();
    let child = demo_command(&["--quiet", "--serve"], &dir.path().join("demo"))
        .stdout(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut child = Running(child);
    let stdout = child.0.stdout.take().unwrap();
    // The printed URL, read on a thread (the pipe stays open while the server runs).
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            if let Some(rest) = line.strip_prefix("live view: ") {
                let url = rest.split_whitespace().next().unwrap_or("").to_string();
                let _ = tx.send(url);
            }
        }
    });
    let url = rx
        .recv_timeout(std::time::Duration::from_secs(300))
        .expect("demo --serve printed no live view URL");
    assert!(
        url.starts_with("http://127.0.0.1:") && url.ends_with("/ui"),
        "{url}"
    );
    let http = reqwest::Client::new();
    let page = http.get(&url).send().await.unwrap();
    assert_eq!(page.status(), 200);
    assert!(page.text().await.unwrap().contains("<html"));
    // The robots keep coming: live sessions appear.
    let sessions_url = url.replace("/ui", "/v1/sessions");
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(60);
    let mut live = 0;
    while live == 0 && std::time::Instant::now() < deadline {
        let body: Value = http
            .get(&sessions_url)
            .send()
            .await
            .unwrap()
            .json()
            .await
            .unwrap();
        live = body["sessions"].as_array().map_or(0, Vec::len);
        if live == 0 {
            tokio::time::sleep(std::time::Duration::from_millis(200)).await;
        }
    }
    assert!(live > 0, "no live session after the demo");
    // Ctrl-C: a clean stop.
    let pid = child.0.id().to_string();
    let killed = Command::new("kill").args(["-INT", &pid]).status().unwrap();
    assert!(killed.success());
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(30);
    let status = loop {
        if let Some(s) = child.0.try_wait().unwrap() {
            break s;
        }
        assert!(
            std::time::Instant::now() < deadline,
            "demo --serve did not stop on SIGINT"
        );
        std::thread::sleep(std::time::Duration::from_millis(100));
    };
    assert!(status.success(), "{status:?}");
}

/// Without ONNX Runtime (here: `ORT_DYLIB_PATH` naming no file; on a robot PC: no library
/// and no network to fetch one) the embedded demo runs its model-free profile and says
/// so; `--no-model` asks for it. Every image is scored and the anomalies still alarm.
#[test]
fn without_onnx_runtime_the_demo_runs_without_the_model() {
    let dir = tempfile::tempdir().unwrap();
    for (args, env_path) in [
        (&["--quiet"][..], Some("/nonexistent/libonnxruntime.so")),
        (&["--quiet", "--no-model"][..], None),
    ] {
        let out_dir = dir.path().join(if env_path.is_some() {
            "fallback"
        } else {
            "asked"
        });
        let mut cmd = demo_command(args, &out_dir);
        if let Some(p) = env_path {
            cmd.env("ORT_DYLIB_PATH", p);
        }
        let out = cmd.output().unwrap();
        let stdout = String::from_utf8_lossy(&out.stdout);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{args:?} failed:\n{stdout}\n{stderr}");
        assert_eq!(
            stdout.contains("ONNX Runtime is not available (ORT_DYLIB_PATH="),
            env_path.is_some(),
            "{stdout}"
        );
        assert!(!stdout.contains("ONNX Runtime: "), "{stdout}");
        assert!(
            stdout.contains("profile \"demo-no-model\", model none"),
            "{stdout}"
        );
        let report = read_report(&out_dir);
        assert_eq!(report["profile"], "demo-no-model");
        assert_eq!(report["frames_scored"], report["images_sent"]);
        let alarmed = report["episodes"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|e| !e["first_alarm_ns"].is_null())
            .count();
        assert!(alarmed >= 3, "{alarmed} episodes with an alarm: {report}");
    }
}
