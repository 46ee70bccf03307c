//! Forward kinematics against pybullet, and loading robots from every kind of source.
//!
//! Fixtures: pybullet_data's `franka_panda` and `kuka_iiwa` (URDF + meshes) and
//! `fk_*.json`, link poses written by `tests/fixtures/robot/generate_fk.py` with pybullet's
//! `getLinkState(..., computeForwardKinematics=True)` (link frames, not centres of mass).
//! Tolerance 1e-6 m and 1e-6 rad (measured: at most 1.1e-7 m and 5.3e-7 rad; pybullet's
//! orientations carry less than double precision): it absorbs that rounding, while any
//! convention error (rpy order, axis frame, mimic sign) shows as millimetres or degrees.

use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};
use serde_json::Value;
use std::io::Write;
use std::path::{Path, PathBuf};
use vamos::robot::{JointKind, Robot, RobotConfig, RobotError};

const TOL: f64 = 1e-6;

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/robot")
}

fn reference(name: &str) -> Value {
    let text = std::fs::read_to_string(fixtures().join(format!("fk_{name}.json"))).unwrap();
    serde_json::from_str(&text).unwrap()
}

fn pose_of(v: &Value) -> Isometry3<f64> {
    let t: Vec<f64> = serde_json::from_value(v["translation"].clone()).unwrap();
    let q: Vec<f64> = serde_json::from_value(v["rotation_xyzw"].clone()).unwrap();
    Isometry3::from_parts(
        Translation3::new(t[0], t[1], t[2]),
        UnitQuaternion::from_quaternion(Quaternion::new(q[3], q[0], q[1], q[2])),
    )
}

/// Largest translation (m) and rotation (rad) error over all links and configurations;
/// also checks every link of the reference is present and out-of-limit flags agree.
fn compare(robot: &Robot, name: &str) -> (f64, f64) {
    let reference = reference(name);
    let configs = reference["configs"].as_array().unwrap();
    assert_eq!(configs.len(), 20);
    let mut mapper = robot.joint_mapper();
    let (mut worst_t, mut worst_r) = (0.0f64, 0.0f64);
    let mut flagged = 0;
    for c in configs {
        let joints = c["joints"].as_object().unwrap();
        let mapped = mapper
            .map_pairs(
                joints
                    .iter()
                    .map(|(k, v)| (k.as_str(), v.as_f64().unwrap())),
            )
            .unwrap();
        assert_eq!(mapped.unknown, 0);
        assert!(mapped.missing.is_empty(), "{:?}", mapped.missing);
        let poses = robot.forward(&mapped.positions).unwrap();
        let expected = c["poses"].as_object().unwrap();
        assert_eq!(expected.len(), robot.links().len());
        for (link, want) in expected {
            let i = robot.kinematics().link_index(link).unwrap();
            let want = pose_of(want);
            let got = poses[i];
            worst_t = worst_t.max((got.translation.vector - want.translation.vector).norm());
            worst_r = worst_r.max(got.rotation.angle_to(&want.rotation));
        }
        let mut outside: Vec<String> = robot
            .out_of_limits(&mapped.positions)
            .into_iter()
            .map(|v| v.joint)
            .collect();
        outside.sort();
        let want: Vec<String> = serde_json::from_value(c["out_of_limits"].clone()).unwrap();
        assert_eq!(outside, want);
        flagged += usize::from(!want.is_empty());
    }
    assert!(flagged >= 4, "{flagged} configurations outside limits");
    eprintln!(
        "{name}: worst {worst_t:e} m, {worst_r:e} rad over {} configurations",
        configs.len()
    );
    (worst_t, worst_r)
}

fn load(rel: &str) -> Robot {
    Robot::load(&fixtures().join(rel), &RobotConfig::default()).unwrap()
}

#[test]
fn panda_matches_pybullet() {
    let robot = load("franka_panda/panda.urdf");
    assert_eq!(robot.name(), "panda");
    assert_eq!(robot.links()[robot.root()], "panda_link0");
    assert!(robot.warnings().is_empty(), "{:?}", robot.warnings());
    let finger2 = &robot.joints()[robot
        .kinematics()
        .joint_index("panda_finger_joint2")
        .unwrap()];
    assert_eq!(finger2.kind, JointKind::Prismatic);
    assert!(finger2.mimic.is_some());
    let (t, r) = compare(&robot, "franka_panda");
    assert!(t < TOL && r < TOL, "panda: {t} m, {r} rad");
    // Every link with a visual has a mesh, and the merged meshes are welded (far fewer
    // vertices than the 3 per triangle the OBJ loader returns).
    assert_eq!(robot.link_meshes().len(), 11);
    let tris = robot.triangle_count();
    let verts: usize = robot
        .link_meshes()
        .iter()
        .map(|m| m.mesh.positions.len())
        .sum();
    assert!(tris > 100_000, "{tris}");
    assert!(verts < tris, "{verts} vertices for {tris} triangles");
    assert!(robot.link_meshes().iter().all(|m| m.mesh.is_valid()));
}

#[test]
fn kuka_matches_pybullet() {
    let robot = load("kuka_iiwa/model.urdf");
    assert!(robot.warnings().is_empty(), "{:?}", robot.warnings());
    let (t, r) = compare(&robot, "kuka_iiwa");
    assert!(t < TOL && r < TOL, "kuka: {t} m, {r} rad");
    assert_eq!(robot.link_meshes().len(), 8);
}

fn poses(robot: &Robot) -> Vec<Isometry3<f64>> {
    let reference = reference("franka_panda");
    let joints = reference["configs"][3]["joints"]
        .as_object()
        .unwrap()
        .clone();
    let mut mapper = robot.joint_mapper();
    let q = mapper
        .map_pairs(
            joints
                .iter()
                .map(|(k, v)| (k.as_str(), v.as_f64().unwrap())),
        )
        .unwrap()
        .positions;
    robot.forward(&q).unwrap()
}

fn same_robot(a: &Robot, b: &Robot) {
    assert_eq!(a.links(), b.links());
    assert_eq!(a.triangle_count(), b.triangle_count());
    assert!(b.warnings().is_empty(), "{:?}", b.warnings());
    for (p, q) in poses(a).iter().zip(poses(b).iter()) {
        assert!((p.translation.vector - q.translation.vector).norm() < 1e-12);
    }
}

/// Adds the panda folder under `franka_panda/` to a tar.gz and a zip.
fn archives(dir: &Path) -> (PathBuf, PathBuf) {
    let src = fixtures().join("franka_panda");
    let tgz = dir.join("panda.tar.gz");
    let gz = flate2::write::GzEncoder::new(
        std::fs::File::create(&tgz).unwrap(),
        flate2::Compression::fast(),
    );
    let mut tar = tar::Builder::new(gz);
    tar.append_dir_all("franka_panda", &src).unwrap();
    tar.into_inner().unwrap().finish().unwrap();
    let zip_path = dir.join("panda.zip");
    let mut zip = zip::ZipWriter::new(std::fs::File::create(&zip_path).unwrap());
    let opts = zip::write::SimpleFileOptions::default()
        .compression_method(zip::CompressionMethod::Deflated);
    let mut stack = vec![src.clone()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                let rel = p.strip_prefix(&src).unwrap();
                zip.start_file(format!("franka_panda/{}", rel.display()), opts)
                    .unwrap();
                zip.write_all(&std::fs::read(&p).unwrap()).unwrap();
            }
        }
    }
    zip.finish().unwrap();
    (tgz, zip_path)
}

#[test]
fn panda_from_folder_tar_gz_and_zip_gives_the_same_poses() {
    let file = load("franka_panda/panda.urdf");
    let dir = tempfile::tempdir().unwrap();
    let (tgz, zip) = archives(dir.path());
    let cfg = RobotConfig::default();
    same_robot(
        &file,
        &Robot::load(&fixtures().join("franka_panda"), &cfg).unwrap(),
    );
    let from_tgz = Robot::load(&tgz, &cfg).unwrap();
    same_robot(&file, &from_tgz);
    same_robot(&file, &Robot::load(&zip, &cfg).unwrap());
    // Mesh paths inside the archive are reported as archive!/entry.
    let v = &from_tgz.visuals(0)[0];
    let text = serde_json::to_string(v).unwrap();
    assert!(
        text.contains("panda.tar.gz!/franka_panda/meshes/collision/link0.obj"),
        "{text}"
    );
    // A cap on unpacked bytes is a typed error.
    let small = RobotConfig {
        max_archive_bytes: 1 << 20,
        ..RobotConfig::default()
    };
    let e = Robot::load(&zip, &small).unwrap_err();
    assert!(
        matches!(e, RobotError::ArchiveTooLarge { what: "bytes", .. }),
        "{e}"
    );
}

#[test]
fn urdf_string_with_relative_meshes_resolves_against_the_given_root() {
    let root = fixtures().join("kuka_iiwa");
    let xml = std::fs::read_to_string(root.join("model.urdf")).unwrap();
    let cfg = RobotConfig::default();
    let from_file = load("kuka_iiwa/model.urdf");
    let from_str = Robot::from_urdf_str(&xml, Some(&root), &cfg).unwrap();
    assert!(from_str.warnings().is_empty(), "{:?}", from_str.warnings());
    assert_eq!(from_str.triangle_count(), from_file.triangle_count());
    // Without a root the robot still loads, every mesh reported by name.
    let bare = Robot::from_urdf_str(&xml, None, &cfg).unwrap();
    assert_eq!(bare.triangle_count(), 0);
    assert_eq!(bare.warnings().len(), 8);
    assert!(
        bare.warnings()[0].contains("meshes/link_0.obj"),
        "{:?}",
        bare.warnings()
    );
}

#[test]
fn archive_with_a_parent_dir_entry_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("evil.tar.gz");
    // The tar crate's builder refuses `..`, so write the header by hand.
    let gz = flate2::write::GzEncoder::new(
        std::fs::File::create(&path).unwrap(),
        flate2::Compression::fast(),
    );
    let mut tar = tar::Builder::new(gz);
    let data = b"<robot name=\"x\"><link name=\"a\"/></robot>";
    let mut header = tar::Header::new_gnu();
    header.as_gnu_mut().unwrap().name[..12].copy_from_slice(b"../evil.urdf");
    header.set_size(data.len() as u64);
    header.set_mode(0o644);
    header.set_cksum();
    tar.append(&header, &data[..]).unwrap();
    tar.into_inner().unwrap().finish().unwrap();
    let e = Robot::load(&path, &RobotConfig::default()).unwrap_err();
    assert!(matches!(e, RobotError::ArchiveUnsafeEntry { .. }), "{e}");
}

#[test]
fn cli_robot_inspect_prints_one_json_object_with_poses() {
    let dir = tempfile::tempdir().unwrap();
    let reference = reference("kuka_iiwa");
    let config = &reference["configs"][19];
    let joints = dir.path().join("joints.json");
    let mut given = config["joints"].as_object().unwrap().clone();
    given.insert("not_a_joint".into(), serde_json::json!(1.0));
    std::fs::write(&joints, serde_json::to_string(&given).unwrap()).unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_vamos"))
        .args(["robot", "inspect", "--robot"])
        .arg(fixtures().join("kuka_iiwa/model.urdf"))
        .arg("--joints")
        .arg(&joints)
        .env_remove("VAMOS_CONFIG")
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["robot"], "lbr_iiwa");
    assert_eq!(v["root"], "lbr_iiwa_link_0");
    assert_eq!(v["joints"].as_array().unwrap().len(), 7);
    assert_eq!(v["joints"][0]["type"], "revolute");
    assert_eq!(v["links"].as_array().unwrap().len(), 8);
    assert!(
        v["links"][1]["visuals"][0]["resolved"]
            .as_str()
            .unwrap()
            .ends_with("meshes/link_1.obj")
    );
    assert_eq!(v["warnings"].as_array().unwrap().len(), 0);
    assert_eq!(v["unknown_joints"], 1);
    for (link, want) in config["poses"].as_object().unwrap() {
        let got = pose_of(&v["poses"][link]);
        let want = pose_of(want);
        assert!(
            (got.translation.vector - want.translation.vector).norm() < TOL,
            "{link}"
        );
        assert!(got.rotation.angle_to(&want.rotation) < TOL, "{link}");
    }
    let names: Vec<&str> = v["out_of_limits"]
        .as_array()
        .unwrap()
        .iter()
        .map(|o| o["joint"].as_str().unwrap())
        .collect();
    let want: Vec<String> = serde_json::from_value(config["out_of_limits"].clone()).unwrap();
    assert_eq!(names, want);
    // A broken URDF is a clean failure naming the problem.
    let bad = dir.path().join("bad.urdf");
    std::fs::write(&bad, "<robot name=\"x\"><link name=\"a\">").unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_vamos"))
        .args(["robot", "inspect", "--robot"])
        .arg(&bad)
        .env_remove("VAMOS_CONFIG")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("malformed URDF"),
        "{err}"
    );
    assert!(!err.contains("panicked"), "{err}");
}
