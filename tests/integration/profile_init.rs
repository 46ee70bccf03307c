//! A new robot whose URDF names ROS packages: `vamos profile init` finds the packages
//! (`--packages`, beside the episode), fails naming the meshes it cannot find, or goes on
//! with `--allow-missing-meshes` and says what is missing; the profile it writes scores
//! with the body in view. And the fallbacks `vamos calibrate` and `vamos score` used to
//! take silently: the conformal threshold without enough held-out episodes, detectors
//! that cannot run.
//!
//! The robot is the simulated arm of tests/fixtures/sim with every visual primitive made
//! a mesh file (OBJ, tessellated by vamos's own primitives) of a package `absent_pkg`; the
//! bag is a copy of a simulated episode whose robot description is that URDF.

use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use vamos::episode::ros::encode_string;
use vamos::episode::{EpisodeConfig, McapEpisode, ScoreBagWriter};
use vamos::robot::TriMesh;
use vamos::robot::mesh::{box_mesh, cylinder_mesh, sphere_mesh};

const PACKAGE: &str = "absent_pkg";

fn sim() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/sim")
}

/// Runs vamos in `dir` without ROS's package variables (the search must not depend on the
/// machine running the tests).
fn vamos(dir: &Path, args: &[&str]) -> Output {
    let out = Command::new(env!("CARGO_BIN_EXE_vamos"))
        .current_dir(dir)
        .args(args)
        .env("VAMOS_LOG__LEVEL", "warn")
        .env_remove("ROS_PACKAGE_PATH")
        .env_remove("AMENT_PREFIX_PATH")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!stderr.contains("panicked"), "{stderr}");
    out
}

fn ok(out: &Output) -> String {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// The value of attribute `name` in the XML tag `tag` (`<box size="1 2 3"/>`).
fn attr<'a>(tag: &'a str, name: &str) -> &'a str {
    let key = format!("{name}=\"");
    let start = tag.find(&key).unwrap() + key.len();
    let len = tag[start..].find('"').unwrap();
    &tag[start..start + len]
}

fn numbers(s: &str) -> Vec<f64> {
    s.split_whitespace().map(|v| v.parse().unwrap()).collect()
}

fn obj(mesh: &TriMesh) -> String {
    let mut text = String::new();
    for p in &mesh.positions {
        text.push_str(&format!("v {} {} {}\n", p.x, p.y, p.z));
    }
    for t in &mesh.triangles {
        text.push_str(&format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1));
    }
    text
}

/// The simulated arm's URDF with each visual's primitive replaced by
/// `package://absent_pkg/meshes/visual_<i>.obj`, and those files (path in the package,
/// OBJ text).
fn meshed_robot() -> (String, Vec<(String, String)>) {
    let urdf = std::fs::read_to_string(sim().join("robot/vamos_arm.urdf")).unwrap();
    let mut out = String::new();
    let mut files = Vec::new();
    let mut rest = urdf.as_str();
    while let Some(at) = rest.find("<visual>") {
        let end = at + rest[at..].find("</visual>").unwrap();
        let visual = &rest[at..end];
        let g0 = visual.find("<geometry>").unwrap() + "<geometry>".len();
        let g1 = visual.find("</geometry>").unwrap();
        let tag = &visual[g0..g1];
        let mesh = if tag.starts_with("<box") {
            let s = numbers(attr(tag, "size"));
            box_mesh([s[0], s[1], s[2]])
        } else if tag.starts_with("<cylinder") {
            cylinder_mesh(
                attr(tag, "radius").parse().unwrap(),
                attr(tag, "length").parse().unwrap(),
                24,
            )
        } else if tag.starts_with("<sphere") {
            sphere_mesh(attr(tag, "radius").parse().unwrap(), 8)
        } else {
            panic!("unexpected visual geometry {tag}")
        };
        let path = format!("meshes/visual_{}.obj", files.len());
        out.push_str(&rest[..at]);
        out.push_str(&visual[..g0]);
        out.push_str(&format!("<mesh filename=\"package://{PACKAGE}/{path}\"/>"));
        out.push_str(&visual[g1..]);
        files.push((path, obj(&mesh)));
        rest = &rest[end..];
    }
    out.push_str(rest);
    assert!(files.len() > 10, "the arm has {} visuals", files.len());
    (out, files)
}

/// A copy of the bag `src` whose robot description is `urdf`.
fn bag_with_description(src: &Path, dst: &Path, urdf: &str) {
    let ep = McapEpisode::open(src, &EpisodeConfig::default()).unwrap();
    let description = ep.info().chosen.robot_description.clone().unwrap();
    let topics: Vec<String> = ep.info().topics.iter().map(|t| t.name.clone()).collect();
    let schemas: std::collections::HashMap<String, (String, String, Vec<u8>)> = topics
        .iter()
        .map(|t| (t.clone(), ep.schema_of(t).unwrap().unwrap()))
        .collect();
    let replaced = encode_string(urdf);
    std::fs::create_dir_all(dst.parent().unwrap()).unwrap();
    let mut w = ScoreBagWriter::create(dst, None).unwrap();
    let mut written = Ok(());
    ep.for_each_message(&topics, |topic, _, log_time, cdr| {
        let (name, encoding, data) = &schemas[topic];
        let message = if topic == description { &replaced } else { cdr };
        if written.is_ok() {
            written = w.copy_message(topic, name, encoding, data, message, log_time);
        }
    })
    .unwrap();
    written.unwrap();
    w.finish().unwrap();
}

/// Writes the package `absent_pkg` (package.xml and meshes) into `dir`.
fn write_package(dir: &Path, files: &[(String, String)]) {
    let root = dir.join(PACKAGE);
    std::fs::create_dir_all(root.join("meshes")).unwrap();
    std::fs::write(
        root.join("package.xml"),
        format!(
            "<?xml version=\"1.0\"?>\n<package format=\"3\"><name>{PACKAGE}</name></package>\n"
        ),
    )
    .unwrap();
    for (path, text) in files {
        std::fs::write(root.join(path), text).unwrap();
    }
}

/// Scores `bag` with `profile` into `out`: the summary line and each frame's body pixels.
fn score(dir: &Path, profile: &Path, bag: &Path, out: &str) -> (Value, Vec<u64>) {
    let stdout = ok(&vamos(
        dir,
        &[
            "score",
            "--profile",
            profile.to_str().unwrap(),
            bag.to_str().unwrap(),
            "-o",
            out,
        ],
    ));
    let summary: Value = serde_json::from_str(stdout.trim()).unwrap();
    let frames = std::fs::read_to_string(dir.join(out).join("run.scores.jsonl")).unwrap();
    let pixels = frames
        .lines()
        .map(|l| {
            serde_json::from_str::<Value>(l).unwrap()["body_pixels"]
                .as_u64()
                .unwrap()
        })
        .collect();
    (summary, pixels)
}

fn not_run<'a>(summary: &'a Value, detector: &str) -> Option<&'a str> {
    summary["detectors_not_run"]
        .as_array()
        .unwrap()
        .iter()
        .find(|d| d["detector"] == detector)
        .map(|d| d["reason"].as_str().unwrap())
}

/// `profile init` on a bag whose URDF names a package that is not on disk: a non-zero
/// exit naming the package and each mesh, and how to give them, with nothing left behind;
/// `--packages DIR` finds it, records it in the profile, and that profile scores with the
/// body in view; `--allow-missing-meshes` goes on with the meshes in the notes (and the
/// body then out of view, which the score summary says); a package beside the bag is
/// found without being named.
#[test]
fn profile_init_finds_ros_packages_or_names_the_missing_meshes() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path();
    let (urdf, files) = meshed_robot();
    let bag = root.join("recordings/run.mcap");
    bag_with_description(&sim().join("test/test_0000.mcap"), &bag, &urdf);
    write_package(&root.join("elsewhere"), &files);
    let bag_arg = bag.to_str().unwrap();

    // 1. The package is nowhere vamos looks: the command fails and says what and how.
    let out = vamos(root, &["profile", "init", "--episode", bag_arg, "robot-a"]);
    assert!(!out.status.success());
    assert!(out.stdout.is_empty());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains(&format!(
            "package \"{PACKAGE}\" not found ({} meshes)",
            files.len()
        )),
        "{err}"
    );
    for (path, _) in &files {
        assert!(err.contains(path.as_str()), "{path}: {err}");
    }
    assert!(err.contains("--packages DIR") && err.contains("--allow-missing-meshes"));
    assert!(err.contains("invisible to the camera"), "{err}");
    // Grouped: one line for the package, not a warning per mesh.
    assert_eq!(err.matches(PACKAGE).count(), 1, "{err}");
    assert!(!err.contains("left out"), "{err}");
    assert!(
        !root.join("robot-a/robot.urdf").exists() && !root.join("robot-a/profile.toml").exists(),
        "a failed run leaves nothing behind"
    );

    // 2. --packages: the folder holding the package. Run again as it was, plus the flag.
    let elsewhere = root.join("elsewhere");
    let summary: Value = serde_json::from_str(&ok(&vamos(
        root,
        &[
            "profile",
            "init",
            "--episode",
            bag_arg,
            "--packages",
            elsewhere.to_str().unwrap(),
            "robot-a",
        ],
    )))
    .unwrap();
    let package_dir = std::fs::canonicalize(elsewhere.join(PACKAGE)).unwrap();
    assert_eq!(summary["packages"][0]["package"], PACKAGE);
    assert_eq!(summary["packages"][0]["found_by"], "--packages");
    assert_eq!(
        summary["packages"][0]["path"],
        package_dir.display().to_string()
    );
    assert_eq!(summary["missing_meshes"], serde_json::json!([]));
    assert!(
        summary["next"][0]
            .as_str()
            .unwrap()
            .contains(&format!("--packages {}", package_dir.display())),
        "{summary}"
    );
    let profile = std::fs::read_to_string(root.join("robot-a/profile.toml")).unwrap();
    assert!(
        profile.contains(&format!("robot_packages = [\"{}\"]", package_dir.display())),
        "{profile}"
    );
    // A later load (here `vamos score`) finds the meshes through the profile: the body
    // is in view.
    let (with_meshes, pixels) = score(root, &root.join("robot-a/profile.toml"), &bag, "out-a");
    assert!(pixels.iter().any(|&p| p > 0), "{pixels:?}");
    assert_eq!(not_run(&with_meshes, "e_b"), None, "{with_meshes}");
    // So does the overlay check the init suggests.
    let render: Vec<String> = summary["next"][0]
        .as_str()
        .unwrap()
        .split_whitespace()
        .skip(1)
        .map(str::to_string)
        .collect();
    let render: Vec<&str> = render.iter().map(String::as_str).collect();
    let drawn: Value = serde_json::from_str(&ok(&vamos(root, &render))).unwrap();
    assert!(root.join("overlay.png").is_file(), "{drawn}");

    // 3. --allow-missing-meshes: written, the missing meshes in the notes and the JSON.
    let summary: Value = serde_json::from_str(&ok(&vamos(
        root,
        &[
            "profile",
            "init",
            "--episode",
            bag_arg,
            "--allow-missing-meshes",
            "robot-b",
        ],
    )))
    .unwrap();
    let missing = summary["missing_meshes"].as_array().unwrap();
    assert_eq!(missing.len(), files.len());
    assert!(missing.iter().all(|m| m["package"] == PACKAGE));
    assert_eq!(missing[0]["path"], files[0].0.as_str());
    let notes: Vec<&str> = summary["notes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|n| n.as_str().unwrap())
        .collect();
    let note = notes
        .iter()
        .find(|n| n.contains(&format!("package \"{PACKAGE}\" not found")))
        .unwrap_or_else(|| panic!("{notes:?}"));
    assert!(
        note.contains(&format!("{} meshes left out", files.len()))
            && note.contains(&files[0].0)
            && note.contains("invisible to the camera")
            && note.contains("--packages DIR"),
        "{note}"
    );
    // Each missing mesh is there once, not again among the other warnings.
    assert_eq!(
        summary["robot_warnings"],
        serde_json::json!([]),
        "{summary}"
    );
    assert!(
        !std::fs::read_to_string(root.join("robot-b/profile.toml"))
            .unwrap()
            .contains("robot_packages")
    );
    // Scored, the body is never in view, and the summary says why e_b gave nothing.
    let (without, pixels) = score(root, &root.join("robot-b/profile.toml"), &bag, "out-b");
    assert!(pixels.iter().all(|&p| p == 0), "{pixels:?}");
    assert!(
        not_run(&without, "e_b").is_some_and(|r| r.contains("never in view")),
        "{without}"
    );

    // 4. A colcon-style src/ beside the bag's folder is searched without being named.
    std::fs::create_dir_all(root.join("src")).unwrap();
    std::fs::rename(elsewhere.join(PACKAGE), root.join("src").join(PACKAGE)).unwrap();
    let summary: Value = serde_json::from_str(&ok(&vamos(
        root,
        &["profile", "init", "--episode", bag_arg, "robot-c"],
    )))
    .unwrap();
    assert_eq!(summary["packages"][0]["found_by"], "beside the episode");
    assert_eq!(summary["missing_meshes"], serde_json::json!([]));

    // A --packages that is no folder is refused before anything is read.
    let out = vamos(
        root,
        &[
            "profile",
            "init",
            "--episode",
            bag_arg,
            "--packages",
            "nowhere",
            "robot-d",
        ],
    );
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--packages nowhere: not a folder"));
    assert!(!root.join("robot-d").exists());
}

const PROFILE: &str = r#"name = "sim-arm"
robot = "robot/vamos_arm.urdf"
camera = "camera.json"
flow_preset = "realtime"
alarm = "conformal"
[pipeline]
stride = 1
[pipeline.frames]
width = 160
height = 120
variant = "masked"
"#;

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let entry = entry.unwrap();
        let target = to.join(entry.file_name());
        if entry.file_type().unwrap().is_dir() {
            copy_dir(&entry.path(), &target);
        } else {
            std::fs::copy(entry.path(), target).unwrap();
        }
    }
}

/// Too few held-out episodes for the conformal threshold: `vamos calibrate` notes the
/// numbers and the training maximum in force, `vamos score`'s summary names the rule and
/// why; and detectors the profile switches on that cannot run are named with the reason
/// (no flow model: e_o; before calibration: e_k).
#[test]
fn calibrate_and_score_say_which_fallbacks_are_in_force() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    copy_dir(&sim(), dir);
    std::fs::write(dir.join("profile.toml"), PROFILE).unwrap();
    let held = "test/test_0000.mcap";

    // Before calibration: no alarms, e_k without nominal states, e_o without a model.
    let stdout = ok(&vamos(dir, &["score", "--profile", "profile.toml", held]));
    let summary: Value = serde_json::from_str(stdout.trim()).unwrap();
    assert_eq!(summary["alarm_rule"]["rule"], "none", "{summary}");
    assert!(summary["alarm_rule"]["threshold"].is_null());
    assert!(
        not_run(&summary, "e_k").is_some_and(|r| r.contains("not calibrated")),
        "{summary}"
    );
    assert!(
        not_run(&summary, "e_o").is_some_and(|r| r.contains("no flow model")),
        "{summary}"
    );
    assert_eq!(not_run(&summary, "e_c"), None, "{summary}");

    // One held-out episode at alpha 0.1 (it needs 9): the note says so.
    let out = vamos(
        dir,
        &[
            "calibrate",
            "--profile",
            "profile.toml",
            "train",
            "--holdout",
            held,
        ],
    );
    let cal: Value = serde_json::from_str(&ok(&out)).unwrap();
    assert!(cal["conformal"].is_null());
    let stderr = String::from_utf8_lossy(&out.stderr);
    let score_max = cal["score_max"].as_f64().unwrap();
    assert!(
        stderr.contains(&format!(
            "note: no conformal threshold: 1 held-out episode given, the conformal threshold \
             at alpha 0.1 needs at least 9; alarms use the training maximum of the fused score \
             ({score_max:.6}) instead"
        )),
        "{stderr}"
    );

    // Scored: the training maximum is in force, and the summary says why.
    let out = vamos(dir, &["score", "--profile", "profile.toml", held]);
    let summary: Value = serde_json::from_str(ok(&out).trim()).unwrap();
    let rule = &summary["alarm_rule"];
    assert_eq!(rule["rule"], "max", "{summary}");
    assert_eq!(rule["fallback"], true);
    assert_eq!(rule["threshold"].as_f64().unwrap(), score_max.next_up());
    let why = rule["why"].as_str().unwrap();
    assert!(
        why.contains("asks for the conformal threshold")
            && why.contains("1 held-out episode was too few")
            && why.contains("training maximum"),
        "{why}"
    );
    assert!(String::from_utf8_lossy(&out.stderr).contains(&format!("note: {why}")));
    // Calibrated: e_k runs now; e_o still has no model.
    assert_eq!(not_run(&summary, "e_k"), None, "{summary}");
    assert!(not_run(&summary, "e_o").is_some());

    // A bag without joint states: e_c, e_b and e_k cannot run, and say so.
    let no_joints = dir.join("no_joints.mcap");
    {
        let ep = McapEpisode::open(&dir.join(held), &EpisodeConfig::default()).unwrap();
        let keep: Vec<String> = ep
            .info()
            .topics
            .iter()
            .map(|t| t.name.clone())
            .filter(|t| Some(t) != ep.info().chosen.joint_states.as_ref())
            .collect();
        let schemas: std::collections::HashMap<String, (String, String, Vec<u8>)> = keep
            .iter()
            .map(|t| (t.clone(), ep.schema_of(t).unwrap().unwrap()))
            .collect();
        let mut w = ScoreBagWriter::create(&no_joints, None).unwrap();
        let mut written = Ok(());
        ep.for_each_message(&keep, |topic, _, log_time, cdr| {
            let (name, encoding, data) = &schemas[topic];
            if written.is_ok() {
                written = w.copy_message(topic, name, encoding, data, cdr, log_time);
            }
        })
        .unwrap();
        written.unwrap();
        w.finish().unwrap();
    }
    let stdout = ok(&vamos(
        dir,
        &["score", "--profile", "profile.toml", "no_joints.mcap"],
    ));
    let summary: Value = serde_json::from_str(stdout.trim()).unwrap();
    assert_eq!(summary["no_joint_states"], true);
    for d in ["e_c", "e_b", "e_k"] {
        assert!(
            not_run(&summary, d).is_some_and(|r| r.contains("no joint states")),
            "{d}: {summary}"
        );
    }
    assert_eq!(not_run(&summary, "e_r"), None, "{summary}");
}
