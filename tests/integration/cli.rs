//! The `vamos` binary end to end: real files in, real files and JSON out, clear errors.

use std::path::Path;
use std::process::{Command, Output};
use vamos::vision::flowio::read_flo;
use vamos::vision::synthetic::{self, Motion};

fn vamos(args: &[&str], env: &[(&str, &str)]) -> Output {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_vamos"));
    cmd.args(args)
        .env_remove("VAMOS_CONFIG")
        .env_remove("RUST_LOG");
    for (k, v) in env {
        cmd.env(k, v);
    }
    cmd.output().expect("the vamos binary runs")
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

fn assert_clean_failure(out: &Output, needle: &str) {
    let err = text(&out.stderr);
    assert!(!out.status.success(), "expected failure, stderr: {err}");
    assert!(err.contains(needle), "stderr lacks {needle:?}: {err}");
    assert!(!err.contains("panicked"), "panic: {err}");
}

fn write_pair(dir: &Path, motion: &Motion) -> vamos::vision::FlowField {
    let (a, b, truth) = synthetic::pair(160, 120, motion, 21);
    a.save_png(&dir.join("a.png")).unwrap();
    b.save_png(&dir.join("b.png")).unwrap();
    truth
}

#[test]
fn flow_writes_colour_image_and_raw_field() {
    let dir = tempfile::tempdir().unwrap();
    let truth = write_pair(dir.path(), &Motion::Translation { dx: 2.0, dy: 1.0 });
    let p = |n: &str| dir.path().join(n).display().to_string();
    let out = vamos(
        &[
            "flow",
            &p("a.png"),
            &p("b.png"),
            "-o",
            &p("f.png"),
            "--raw",
            &p("f.flo"),
            "--threads",
            "1",
            "--timing",
        ],
        &[],
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    let line: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(line["width"], 160);
    assert_eq!(line["threads"], 1);
    assert!(line["ms_min"].as_f64().unwrap() > 0.0);
    let flow = read_flo(&dir.path().join("f.flo")).unwrap();
    let aee = flow.average_endpoint_error(&truth, None).unwrap();
    assert!(aee < 0.2, "forward flow of a (2, 1) shift, AEE {aee}");
    let png = image::open(dir.path().join("f.png")).unwrap();
    assert_eq!((png.width(), png.height()), (160, 120));
}

#[test]
fn register_prints_the_transform_as_json() {
    let dir = tempfile::tempdir().unwrap();
    write_pair(
        dir.path(),
        &Motion::Similarity {
            tx: 3.0,
            ty: -2.0,
            scale: 1.0,
            rotation_deg: 0.0,
        },
    );
    let p = |n: &str| dir.path().join(n).display().to_string();
    let out = vamos(&["register", &p("a.png"), &p("b.png")], &[]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let keys: Vec<&str> = v.as_object().unwrap().keys().map(|k| k.as_str()).collect();
    assert_eq!(keys.len(), 5, "exactly the documented keys: {keys:?}");
    assert!((v["tx"].as_f64().unwrap() - 3.0).abs() < 0.3, "{v}");
    assert!((v["ty"].as_f64().unwrap() + 2.0).abs() < 0.3, "{v}");
    assert!((v["scale"].as_f64().unwrap() - 1.0).abs() < 0.01, "{v}");
    assert!(v["rotation_deg"].as_f64().unwrap().abs() < 0.5, "{v}");
}

#[test]
fn bad_inputs_fail_with_clear_messages() {
    let dir = tempfile::tempdir().unwrap();
    write_pair(dir.path(), &Motion::Translation { dx: 1.0, dy: 0.0 });
    let p = |n: &str| dir.path().join(n).display().to_string();
    let missing = vamos(
        &["flow", &p("nope.png"), &p("b.png"), "-o", &p("f.png")],
        &[],
    );
    assert_clean_failure(&missing, "nope.png");
    // Not an image at all.
    std::fs::write(dir.path().join("junk.png"), b"not a png").unwrap();
    assert_clean_failure(
        &vamos(&["register", &p("junk.png"), &p("b.png")], &[]),
        "junk.png",
    );
    // Different sizes.
    vamos::vision::GrayImage::zeros(80, 60)
        .save_png(&dir.path().join("small.png"))
        .unwrap();
    let mismatch = vamos(
        &["flow", &p("a.png"), &p("small.png"), "-o", &p("f.png")],
        &[],
    );
    assert_clean_failure(&mismatch, "160x120");
    assert_clean_failure(
        &vamos(&["register", &p("a.png"), &p("small.png")], &[]),
        "size",
    );
    let preset = vamos(
        &[
            "flow",
            &p("a.png"),
            &p("b.png"),
            "-o",
            &p("f.png"),
            "--preset",
            "warp9",
        ],
        &[],
    );
    assert_clean_failure(&preset, "warp9");
}

#[test]
fn settings_come_from_file_and_environment() {
    let out = vamos(&["config"], &[("VAMOS_VISION__FLOW__WARPS", "3")]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let toml = text(&out.stdout);
    assert!(toml.contains("warps = 3"), "{toml}");
    assert_clean_failure(
        &vamos(&["config"], &[("VAMOS_VISION__WRAPS", "3")]),
        "wraps",
    );
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("v.toml");
    std::fs::write(&file, "[log]\nformat = \"json\"\nlevel = \"debug\"\n").unwrap();
    let out = vamos(&["--config", &file.display().to_string(), "config"], &[]);
    assert!(out.status.success());
    assert!(text(&out.stdout).contains("format = \"json\""));
    // JSON logs on stderr, one object per line.
    let first = text(&out.stderr)
        .lines()
        .next()
        .map(str::to_owned)
        .unwrap_or_default();
    assert!(
        serde_json::from_str::<serde_json::Value>(&first).is_ok(),
        "not JSON: {first}"
    );
}

#[test]
fn vision_demo_runs_on_the_synthetic_pairs() {
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("demo");
    let out = vamos(
        &[
            "demo",
            "--vision",
            "--out",
            &out_dir.display().to_string(),
            "--width",
            "160",
            "--height",
            "120",
        ],
        &[],
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out_dir.join("summary.json")).unwrap())
            .unwrap();
    let cases = summary.as_array().unwrap();
    assert_eq!(cases.len(), 4);
    for c in cases {
        let aee = c["default"]["aee_px"].as_f64().unwrap();
        assert!(aee < 0.5, "{}: AEE {aee}", c["case"]);
    }
    assert!(out_dir.join("translation_flow_default.png").is_file());
}

#[test]
fn output_paths_are_checked_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("no_such_dir/report.json");
    let sim = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/sim/test");
    // The profile does not even exist: the output is checked first.
    let out = vamos(
        &[
            "eval",
            "--profile",
            dir.path().join("nothing.toml").to_str().unwrap(),
            "--episodes",
            sim.to_str().unwrap(),
            "--json",
            missing.to_str().unwrap(),
        ],
        &[],
    );
    assert_clean_failure(&out, "does not exist");
    assert!(
        text(&out.stderr).contains("--json"),
        "{}",
        text(&out.stderr)
    );
    let file = dir.path().join("file");
    std::fs::write(&file, "x").unwrap();
    let plots = file.join("plots");
    let out = vamos(
        &[
            "score",
            "--profile",
            "nothing.toml",
            sim.to_str().unwrap(),
            "--out",
            plots.to_str().unwrap(),
        ],
        &[],
    );
    assert_clean_failure(&out, "is a file, not a folder");
}

#[test]
fn completions_and_man_pages_come_from_the_cli_definition() {
    let out = vamos(&["completions", "bash"], &[]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let script = text(&out.stdout);
    // Sub-commands and their flags are completed.
    for word in ["render", "calibrate", "--episode", "--frame", "completions"] {
        assert!(script.contains(word), "bash completion lacks {word}");
    }
    let out = vamos(&["completions", "zsh"], &[]);
    assert!(out.status.success() && text(&out.stdout).contains("#compdef vamos"));
    let out = vamos(&["completions", "nushell"], &[]);
    assert!(!out.status.success());

    let out = vamos(&["man"], &[]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let page = text(&out.stdout);
    assert!(
        page.starts_with(".ie") || page.contains(".TH vamos"),
        "{page}"
    );
    assert!(page.contains("serve"), "the page lists the sub-commands");
    let dir = tempfile::tempdir().unwrap();
    let out = vamos(&["man", "--dir", dir.path().to_str().unwrap()], &[]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let render = std::fs::read_to_string(dir.path().join("vamos-render.1")).unwrap();
    assert!(render.contains("vamos\\-render") || render.contains("vamos-render"));
    assert!(render.contains("episode"), "{render}");
    assert!(dir.path().join("vamos.1").is_file());
    // Nested commands have their pages too, named by the whole command.
    let init = std::fs::read_to_string(dir.path().join("vamos-profile-init.1")).unwrap();
    assert!(init.contains("episode"), "{init}");
    assert!(dir.path().join("vamos-robot-inspect.1").is_file());
    // A free-string option with fixed values is completed with them.
    let out = vamos(&["completions", "bash"], &[]);
    assert!(
        text(&out.stdout).contains("realtime-hq"),
        "flow --preset values"
    );
    let out = vamos(
        &["man", "--dir", dir.path().join("none").to_str().unwrap()],
        &[],
    );
    assert_clean_failure(&out, "not an existing folder");
}

/// `vamos profile init`: a starting profile from one bag (its CameraInfo, its topics, the
/// URDF it carries) that loads and scores; outputs are checked before work, a wrong
/// camera link is named with the candidates.
#[test]
fn profile_init_writes_a_working_profile_from_a_bag() {
    let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/sim");
    let bag = fixtures.join("test/test_0000.mcap");
    let bag = bag.to_str().unwrap();
    let dir = tempfile::tempdir().unwrap();
    let new = dir.path().join("new-robot");
    let out = vamos(
        &["profile", "init", "--episode", bag, new.to_str().unwrap()],
        &[],
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    let summary: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(summary["camera_frame"], "head_camera_optical_frame");
    assert_eq!(summary["processing"], serde_json::json!([160, 120]));
    // The camera is the one the simulator wrote beside its bags.
    let camera: serde_json::Value =
        serde_json::from_slice(&std::fs::read(new.join("camera.json")).unwrap()).unwrap();
    let truth: serde_json::Value =
        serde_json::from_slice(&std::fs::read(fixtures.join("camera.json")).unwrap()).unwrap();
    assert_eq!(camera, truth);
    // The URDF is the bag's robot description, the same robot as the fixture's file.
    let urdf = std::fs::read_to_string(new.join("robot.urdf")).unwrap();
    assert!(urdf.contains("<robot") && urdf.contains("head_camera_optical_frame"));
    let profile = std::fs::read_to_string(new.join("profile.toml")).unwrap();
    assert!(profile.contains("name = \"new-robot\""), "{profile}");
    assert!(
        profile.contains("image = \"/camera/image_raw\""),
        "{profile}"
    );
    // It scores the bag it came from, every frame after the first.
    let out = vamos(
        &[
            "score",
            "--profile",
            new.join("profile.toml").to_str().unwrap(),
            bag,
        ],
        &[],
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    let scored: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(scored["frames"].as_u64().unwrap() > 10, "{scored}");
    assert_eq!(scored["no_joint_states"], false);

    // Existing files are kept unless --force; nothing is read first.
    let before = std::fs::read(new.join("profile.toml")).unwrap();
    let out = vamos(
        &[
            "profile",
            "init",
            "--episode",
            "/nonexistent.mcap",
            new.to_str().unwrap(),
        ],
        &[],
    );
    assert_clean_failure(&out, "exists; pass --force");
    assert_eq!(std::fs::read(new.join("profile.toml")).unwrap(), before);
    // A camera link the robot lacks: named, with the links that look like cameras.
    let out = vamos(
        &[
            "profile",
            "init",
            "--episode",
            bag,
            "--camera-frame",
            "wrist_cam",
            "--force",
            new.to_str().unwrap(),
        ],
        &[],
    );
    assert_clean_failure(&out, "\"wrist_cam\" is not a link");
    assert!(text(&out.stderr).contains("head_camera_optical_frame"));
}

/// Log lines to a pipe or a file are plain text: no terminal colour codes.
#[test]
fn logs_written_to_a_pipe_carry_no_colour_codes() {
    let out = vamos(&["--log-level", "debug", "model", "runtime"], &[]);
    let err = text(&out.stderr);
    assert!(
        err.contains("onnxruntime") || err.contains("ONNX Runtime"),
        "{err}"
    );
    assert!(
        !err.contains('\u{1b}'),
        "colour codes in piped logs: {err:?}"
    );
}
