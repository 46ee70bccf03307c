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

#[test]
fn model_versions_count_up_never_reuse_and_switch_active() {
    let dir = tempfile::tempdir().unwrap();
    let store = open(dir.path());
    let payloads: [&[u8]; 3] = [b"first bundle", b"second bundle, longer", b"third"];
    for (i, p) in payloads.iter().enumerate() {
        let info = commit_model(&store, "m", p);
        assert_eq!(info.version, i as u32 + 1);
        assert_eq!(info.sha256, sha256_hex(p));
        assert_eq!(info.size_bytes, p.len() as u64);
        assert_eq!(info.summary, json!({"len": p.len()}));
    }
    let m = store.model("m").unwrap();
    assert_eq!(m.active, Some(1), "the first version becomes active");
    assert_eq!(
        m.versions.iter().map(|v| v.version).collect::<Vec<_>>(),
        [1, 2, 3]
    );
    let (v, path) = store.model_path("m", None).unwrap();
    assert_eq!(v, 1);
    assert_eq!(std::fs::read(&path).unwrap(), payloads[0]);
    assert_eq!(path, store.dir().join("models/m/1.vamos"));

    store.set_active_model("m", 3).unwrap();
    let (v, path) = store.model_path("m", None).unwrap();
    assert_eq!(
        (v, std::fs::read(path).unwrap().as_slice()),
        (3, payloads[2])
    );
    let (v, path) = store.model_path("m", Some(2)).unwrap();
    assert_eq!(
        (v, std::fs::read(path).unwrap().as_slice()),
        (2, payloads[1])
    );

    // The active version with others left: refused; another version: deleted.
    let e = store.delete_model("m", Some(3)).unwrap_err();
    assert!(matches!(e, StoreError::InUse { .. }), "{e}");
    assert_eq!(e.kind(), StoreErrorKind::Conflict);
    store.delete_model("m", Some(2)).unwrap();
    assert!(!store.dir().join("models/m/2.vamos").exists());
    let e = store.model_path("m", Some(2)).unwrap_err();
    assert!(
        matches!(&e, StoreError::NotFound { kind: "model version", name } if name == "m@2"),
        "{e}"
    );
    assert!(matches!(
        store.set_active_model("m", 2),
        Err(StoreError::NotFound { .. })
    ));
    store.set_active_model("m", 1).unwrap();
    store.delete_model("m", Some(3)).unwrap();
    // Numbers are not reused after deletes.
    assert_eq!(commit_model(&store, "m", b"fourth").version, 4);
    let m = store.model("m").unwrap();
    assert_eq!(
        m.versions.iter().map(|v| v.version).collect::<Vec<_>>(),
        [1, 4]
    );
    assert_eq!(m.active, Some(1));
    assert_eq!(
        entries(&store.dir().join("models/m")),
        ["1.vamos", "4.vamos", "index.json"]
    );

    // The last version deleted: the model stays, empty, and keeps its numbering.
    commit_model(&store, "solo", b"only");
    store.delete_model("solo", Some(1)).unwrap();
    let solo = store.model("solo").unwrap();
    assert_eq!((solo.active, solo.versions.len()), (None, 0));
    assert!(matches!(
        store.model_path("solo", None),
        Err(StoreError::NotFound { .. })
    ));
    let again = commit_model(&store, "solo", b"again");
    assert_eq!(again.version, 2);
    assert_eq!(store.model("solo").unwrap().active, Some(2));

    // A whole model goes with its numbering.
    store.delete_model("m", None).unwrap();
    assert!(!store.dir().join("models/m").exists());
    assert!(matches!(
        store.model("m"),
        Err(StoreError::NotFound { kind: "model", .. })
    ));
    assert_eq!(
        store
            .models()
            .iter()
            .map(|m| m.name.as_str())
            .collect::<Vec<_>>(),
        ["solo"]
    );
    assert_eq!(commit_model(&store, "m", b"new life").version, 1);
    assert!(entries(&store.dir().join("tmp")).is_empty());
}

#[test]
fn validators_decide_and_a_refusal_leaves_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let store = open(dir.path());
    let u = upload(&store, UploadKind::Model, b"not a bundle");
    let e = store
        .commit_model("m", u, |p| {
            assert!(p.starts_with(store.dir().join("tmp")));
            assert_eq!(std::fs::read(p).unwrap(), b"not a bundle");
            Err("nope".into())
        })
        .unwrap_err();
    assert!(
        matches!(&e, StoreError::Invalid { reason } if reason == "nope"),
        "{e}"
    );
    assert!(store.models().is_empty());
    assert!(entries(&store.dir().join("models")).is_empty());
    assert!(entries(&store.dir().join("tmp")).is_empty());

    // The ready-made bundle validator: a real bundle passes, a damaged one does not.
    let bytes = std::fs::read(fixture("model/valid.vamos")).unwrap();
    let u = upload(&store, UploadKind::Model, &bytes);
    let info = store.commit_model("tiny", u, model_bundle_summary).unwrap();
    assert_eq!(info.summary["name"], "test-tiny");
    assert_eq!(info.sha256, sha256_hex(&bytes));
    let bad = std::fs::read(fixture("model/checksum.vamos")).unwrap();
    let u = upload(&store, UploadKind::Model, &bad);
    let e = store
        .commit_model("tiny", u, model_bundle_summary)
        .unwrap_err();
    assert!(matches!(e, StoreError::Invalid { .. }), "{e}");
    assert_eq!(store.model("tiny").unwrap().versions.len(), 1);
    assert!(entries(&store.dir().join("tmp")).is_empty());

    // Empty uploads and uploads of the wrong kind are refused too.
    let u = store.begin_upload(UploadKind::Model).unwrap();
    let e = store.commit_model("m", u, accept(json!(null))).unwrap_err();
    assert!(e.to_string().contains("empty"), "{e}");
    let u = upload(&store, UploadKind::Model, b"x");
    let e = store.commit_robot("r", u, accept(json!(null))).unwrap_err();
    assert!(matches!(e, StoreError::Invalid { .. }), "{e}");
    // An archive that is not one, before the validator runs.
    let u = upload(
        &store,
        UploadKind::Robot {
            format: RobotFormat::TarGz,
        },
        b"<robot name=\"x\"/>",
    );
    let e = store
        .commit_robot("r", u, |_| panic!("validator must not run"))
        .unwrap_err();
    assert!(e.to_string().contains("not a tar.gz"), "{e}");
    assert!(store.robots().is_empty());
    assert!(entries(&store.dir().join("tmp")).is_empty());
}

#[test]
fn uploads_past_the_limit_are_refused_and_leave_no_temporary_file() {
    let dir = tempfile::tempdir().unwrap();
    let store = Store::open(
        dir.path(),
        StoreLimits {
            max_model_bytes: 10,
            max_robot_bytes: 4,
        },
    )
    .unwrap();
    let mut u = store.begin_upload(UploadKind::Model).unwrap();
    assert_eq!(u.limit_bytes(), 10);
    u.write_chunk(b"123456").unwrap();
    u.write_chunk(b"7890").unwrap();
    assert_eq!(entries(&store.dir().join("tmp")).len(), 1);
    let e = u.write_chunk(b"1").unwrap_err();
    assert!(matches!(e, StoreError::TooLarge { limit_bytes: 10 }), "{e}");
    assert_eq!(e.kind(), StoreErrorKind::TooLarge);
    assert!(
        entries(&store.dir().join("tmp")).is_empty(),
        "deleted at once"
    );
    assert!(matches!(
        u.write_chunk(b""),
        Err(StoreError::TooLarge { .. })
    ));
    let e = store.commit_model("m", u, accept(json!(null))).unwrap_err();
    assert!(matches!(e, StoreError::TooLarge { .. }), "{e}");
    assert!(store.models().is_empty());

    // std::io::Write too (e.g. io::copy from a reader).
    let mut u = store
        .begin_upload(UploadKind::Robot {
            format: RobotFormat::Urdf,
        })
        .unwrap();
    let e = std::io::copy(&mut &b"12345"[..], &mut u).unwrap_err();
    assert!(e.to_string().contains("limit of 4 bytes"), "{e}");
    drop(u);
    assert!(entries(&store.dir().join("tmp")).is_empty());
}

#[test]
fn names_that_are_not_one_plain_component_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let store = open(dir.path());
    let long = "a".repeat(65);
    for bad in [
        "../x",
        "",
        ".hidden",
        "a/b",
        "a\\b",
        "..",
        "x y",
        "é",
        long.as_str(),
    ] {
        assert!(
            matches!(store.model(bad), Err(StoreError::BadName { .. })),
            "{bad:?}"
        );
        let u = upload(&store, UploadKind::Model, b"bytes");
        let e = store.commit_model(bad, u, accept(json!(null))).unwrap_err();
        assert!(matches!(e, StoreError::BadName { .. }), "{bad:?}: {e}");
        let e = store.put_profile(bad, ProfileSpec::default()).unwrap_err();
        assert!(matches!(e, StoreError::BadName { .. }), "{bad:?}: {e}");
        assert_eq!(e.kind(), StoreErrorKind::BadRequest);
    }
    let spec = ProfileSpec {
        robot: Some("../r".into()),
        camera: Some(camera()),
        ..Default::default()
    };
    assert!(matches!(
        store.put_profile("p", spec),
        Err(StoreError::BadName { .. })
    ));
    assert!(entries(&store.dir().join("models")).is_empty());
    assert!(entries(&store.dir().join("profiles")).is_empty());
    // The longest and the most varied good names.
    let good = "a".repeat(64);
    for name in [good.as_str(), "a.b_c-1", "X"] {
        store.put_profile(name, ProfileSpec::default()).unwrap();
    }
    assert_eq!(store.profiles().len(), 3);
}

#[test]
fn robots_round_trip_replace_and_load_from_their_stored_files() {
    let dir = tempfile::tempdir().unwrap();
    let store = open(dir.path());
    let urdf = std::fs::read(fixture("sim/robot/vamos_arm.urdf")).unwrap();
    let direct = Robot::load(
        &fixture("sim/robot/vamos_arm.urdf"),
        &RobotConfig::default(),
    )
    .unwrap();
    let info = commit_urdf(&store, "arm");
    assert_eq!(info.revision, 1);
    assert_eq!(info.format, RobotFormat::Urdf);
    assert_eq!(info.sha256, sha256_hex(&urdf));
    assert_eq!(info.summary["links"], direct.links().len());
    assert_eq!(info.summary["robot_name"], direct.name());
    let path = store.robot_path("arm").unwrap();
    assert_eq!(path, store.dir().join("robots/arm/1.urdf"));
    assert_eq!(std::fs::read(&path).unwrap(), urdf);

    // Replaced by a .tar.gz package with the URDF in a folder: a new revision, the old
    // file gone, Robot::load reads the archive.
    let mut tar_bytes = Vec::new();
    {
        let gz = flate2::write::GzEncoder::new(&mut tar_bytes, flate2::Compression::default());
        let mut tar = tar::Builder::new(gz);
        let mut header = tar::Header::new_gnu();
        header.set_size(urdf.len() as u64);
        header.set_mode(0o644);
        header.set_cksum();
        tar.append_data(&mut header, "arm_pkg/urdf/arm.urdf", urdf.as_slice())
            .unwrap();
        tar.into_inner().unwrap().finish().unwrap();
    }
    let u = upload(
        &store,
        UploadKind::Robot {
            format: RobotFormat::TarGz,
        },
        &tar_bytes,
    );
    let info = store
        .commit_robot("arm", u, |p| robot_summary(p, &RobotConfig::default()))
        .unwrap();
    assert_eq!((info.revision, info.format), (2, RobotFormat::TarGz));
    assert_eq!(
        info.created_unix_s,
        store.robot("arm").unwrap().created_unix_s
    );
    let path = store.robot_path("arm").unwrap();
    assert!(
        path.to_string_lossy().ends_with("robots/arm/2.tar.gz"),
        "{}",
        path.display()
    );
    assert_eq!(
        entries(&store.dir().join("robots/arm")),
        ["2.tar.gz", "meta.json"]
    );
    let loaded = Robot::load(&path, &RobotConfig::default()).unwrap();
    assert_eq!(loaded.links(), direct.links());
    assert_eq!(loaded.joints().len(), direct.joints().len());

    // Stored robots are sealed: a single URDF whose meshes point at the server's files
    // (absolute, file://, escaping with ..) is refused, naming them; a relative mesh of a
    // single URDF has no package to come from and is left out with a warning, never
    // looked up beside the stored file.
    let mesh_urdf = |uri: &str| {
        format!(
            "<robot name=\"m\"><link name=\"a\"><visual><geometry><mesh filename=\"{uri}\"/>\
             </geometry></visual></link></robot>"
        )
    };
    for uri in [
        "/etc/passwd",
        "file:///etc/hostname",
        "../../../../etc/passwd",
        "package://p/../../x.stl",
    ] {
        let u = upload(
            &store,
            UploadKind::Robot {
                format: RobotFormat::Urdf,
            },
            mesh_urdf(uri).as_bytes(),
        );
        let e = store
            .commit_robot("sealed", u, |p| robot_summary(p, &RobotConfig::default()))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("outside the robot package") && e.contains(uri),
            "{e}"
        );
    }
    assert!(store.robot("sealed").is_err());
    let u = upload(
        &store,
        UploadKind::Robot {
            format: RobotFormat::Urdf,
        },
        mesh_urdf("probe.stl").as_bytes(),
    );
    let info = store
        .commit_robot("sealed", u, |p| robot_summary(p, &RobotConfig::default()))
        .unwrap();
    let warnings = info.summary["warnings"].to_string();
    assert!(
        warnings.contains("probe.stl") && warnings.contains("left out"),
        "{warnings}"
    );
    // Even with a mesh file put beside the stored URDF, it is not read.
    let stored = store.robot_path("sealed").unwrap();
    std::fs::write(
        stored.with_file_name("probe.stl"),
        b"solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\n\
          endloop\nendfacet\nendsolid x\n",
    )
    .unwrap();
    let sealed = Robot::load_stored(&stored, &RobotConfig::default()).unwrap();
    assert_eq!(sealed.triangle_count(), 0);
    assert!(
        sealed.warnings()[0].contains("probe.stl"),
        "{:?}",
        sealed.warnings()
    );
    let unsealed = Robot::load(&stored, &RobotConfig::default()).unwrap();
    assert_eq!(unsealed.triangle_count(), 1, "{:?}", unsealed.warnings());
    store.delete_robot("sealed").unwrap();

    // A URDF the validator refuses changes nothing.
    let u = upload(
        &store,
        UploadKind::Robot {
            format: RobotFormat::Urdf,
        },
        b"<robot name=\"broken\"><link name=\"a\"/><joint",
    );
    let e = store
        .commit_robot("arm", u, |p| robot_summary(p, &RobotConfig::default()))
        .unwrap_err();
    assert!(e.to_string().contains("not a loadable robot"), "{e}");
    assert_eq!(store.robot("arm").unwrap().revision, 2);

    assert_eq!(store.robots().len(), 1);
    store.delete_robot("arm").unwrap();
    assert!(store.robots().is_empty());
    assert!(!store.dir().join("robots/arm").exists());
    assert!(matches!(
        store.robot_path("arm"),
        Err(StoreError::NotFound { kind: "robot", .. })
    ));
    assert!(matches!(
        store.delete_robot("arm"),
        Err(StoreError::NotFound { .. })
    ));
    assert_eq!(
        RobotFormat::from_file_name("Arm.TGZ"),
        Some(RobotFormat::TarGz)
    );
    assert_eq!(RobotFormat::from_file_name("a.zip"), Some(RobotFormat::Zip));
    assert_eq!(RobotFormat::from_file_name("a.tar"), None);
}

#[test]
fn profiles_check_their_references_and_protect_what_they_use() {
    let dir = tempfile::tempdir().unwrap();
    let store = open(dir.path());
    let with_robot = |robot: &str| ProfileSpec {
        robot: Some(robot.into()),
        camera: Some(camera()),
        ..Default::default()
    };
    let e = store.put_profile("p", with_robot("ghost")).unwrap_err();
    assert!(
        matches!(&e, StoreError::NotFound { kind: "robot", name } if name == "ghost"),
        "{e}"
    );
    assert_eq!(e.kind(), StoreErrorKind::NotFound);
    commit_urdf(&store, "arm");
    let mut no_camera = with_robot("arm");
    no_camera.camera = None;
    assert!(matches!(
        store.put_profile("p", no_camera),
        Err(StoreError::Invalid { .. })
    ));
    let model = |name: &str, version: Option<u32>| ProfileSpec {
        model: Some(ModelRef {
            name: name.into(),
            version,
        }),
        ..with_robot("arm")
    };
    assert!(matches!(
        store.put_profile("p", model("ghost", None)),
        Err(StoreError::NotFound { kind: "model", .. })
    ));
    commit_model(&store, "m", b"v1");
    commit_model(&store, "m", b"v2");
    assert!(matches!(
        store.put_profile("p", model("m", Some(3))),
        Err(StoreError::NotFound {
            kind: "model version",
            ..
        })
    ));
    let bad_preset = ProfileSpec {
        flow_preset: Some("warp-speed".into()),
        ..Default::default()
    };
    assert!(matches!(
        store.put_profile("p", bad_preset),
        Err(StoreError::Invalid { .. })
    ));
    // Sizes no scorer is built with (a processing resolution of 100000 x 100000 pixels
    // once made scoring abort the server on a 40 GB allocation).
    for pipeline in [
        r#"{"frames": {"width": 100000, "height": 100000}}"#,
        r#"{"frames": {"width": 8, "height": 8}}"#,
        r#"{"offset_a": 1000000000000}"#,
        r#"{"offset_b": 18446744073709551615}"#,
    ] {
        let spec = ProfileSpec {
            pipeline: Some(serde_json::from_str(pipeline).unwrap()),
            ..Default::default()
        };
        let e = store.put_profile("p", spec).unwrap_err();
        assert!(matches!(e, StoreError::Invalid { .. }), "{pipeline}: {e}");
    }
    assert!(store.profiles().is_empty());

    let pinned = store.put_profile("pinned", model("m", Some(2))).unwrap();
    assert_eq!(pinned.spec.model.as_ref().unwrap().version, Some(2));
    store.put_profile("follows", model("m", None)).unwrap();
    // Pinned version, active version followed, whole model, robot: all in use.
    let e = store.delete_model("m", Some(2)).unwrap_err();
    assert!(
        matches!(&e, StoreError::InUse { name, by, .. } if name == "m@2" && by == &["profile pinned"]),
        "{e}"
    );
    let e = store.delete_model("m", Some(1)).unwrap_err();
    let StoreError::InUse { by, .. } = &e else {
        panic!("{e}")
    };
    assert_eq!(by.len(), 2, "{e}");
    assert!(by[1].contains("profile follows"), "{e}");
    let e = store.delete_model("m", None).unwrap_err();
    assert!(
        matches!(&e, StoreError::InUse { by, .. } if by == &["profile follows", "profile pinned"]),
        "{e}"
    );
    let e = store.delete_robot("arm").unwrap_err();
    assert!(matches!(e, StoreError::InUse { kind: "robot", .. }), "{e}");

    // Replacing a profile keeps its creation time; deleting frees what it used.
    let before = store.profile("pinned").unwrap();
    let after = store.put_profile("pinned", with_robot("arm")).unwrap();
    assert_eq!(after.created_unix_s, before.created_unix_s);
    assert!(after.spec.model.is_none());
    store.delete_model("m", Some(2)).unwrap();
    store.delete_profile("pinned").unwrap();
    store.delete_profile("follows").unwrap();
    assert!(matches!(
        store.profile("follows"),
        Err(StoreError::NotFound {
            kind: "profile",
            ..
        })
    ));
    assert!(matches!(
        store.delete_profile("follows"),
        Err(StoreError::NotFound { .. })
    ));
    store.delete_robot("arm").unwrap();
    store.delete_model("m", None).unwrap();
    assert!(entries(&store.dir().join("profiles")).is_empty());

    // The REST body refuses unknown keys.
    let e = serde_json::from_str::<ProfileSpec>(r#"{"robbot": "arm"}"#).unwrap_err();
    assert!(e.to_string().contains("robbot"), "{e}");
}

#[test]
fn resolved_profiles_load_with_setup_and_see_threshold_overrides() {
    let dir = tempfile::tempdir().unwrap();
    let store = open(dir.path());
    commit_urdf(&store, "arm");
    let spec = ProfileSpec {
        robot: Some("arm".into()),
        camera: Some(camera()),
        alarm: AlarmRule::Max,
        flow_preset: Some("realtime".into()),
        ..Default::default()
    };
    let info = store.put_profile("shelf", spec).unwrap();
    assert_eq!(info.thresholds, Thresholds::default());
    assert_eq!(info.alarm_threshold, None);

    let resolved = store.resolve_profile("shelf").unwrap();
    assert!(resolved.model.is_none());
    assert_eq!(resolved.robot.as_deref(), Some("arm"));
    let robot_path = resolved.profile.file.robot.clone().unwrap();
    assert!(robot_path.is_file(), "{}", robot_path.display());
    assert_eq!(robot_path, store.robot_path("arm").unwrap());
    assert!(resolved.profile.calibration.is_none());
    let settings = crate::config::Settings::default();
    let setup = vamos_core::setup::Setup::from_profile(&settings, resolved.profile).unwrap();
    let loaded = setup.robot.as_ref().unwrap();
    assert_eq!(loaded.robot.name(), "vamos_arm");
    assert!(setup.model.is_none());
    assert_eq!(setup.profile.alarm_threshold(), f64::INFINITY);

    // A calibration, then overrides: e_c set, alarm set, then alarm cleared.
    let info = store.save_calibration("shelf", calibration(None)).unwrap();
    assert_eq!(info.calibration.as_ref().unwrap().training_frames, 120);
    assert_eq!(info.alarm_threshold, Some(0.5f64.next_up()), "max rule");
    let patch: ThresholdsPatch = serde_json::from_str(r#"{"e_c": 2.5, "alarm": 9.0}"#).unwrap();
    assert_eq!(patch.e_b, None);
    let info = store.patch_thresholds("shelf", patch).unwrap();
    assert_eq!(info.thresholds, Thresholds::paper(Some(2.5), Some(3.25)));
    assert_eq!(info.alarm_threshold, Some(9.0));
    let p = store.resolve_profile("shelf").unwrap().profile;
    assert_eq!(p.thresholds(), info.thresholds);
    assert_eq!(p.alarm_threshold(), 9.0);
    let setup = vamos_core::setup::Setup::from_profile(&settings, p).unwrap();
    assert_eq!(setup.profile.thresholds().e_c, Some(2.5));

    let patch: ThresholdsPatch = serde_json::from_str(r#"{"alarm": null}"#).unwrap();
    assert_eq!(patch.alarm, Some(None));
    let info = store.patch_thresholds("shelf", patch).unwrap();
    assert_eq!(info.spec.thresholds.e_c, Some(2.5), "left as it was");
    assert_eq!(info.spec.thresholds.alarm, None);
    let p = store.resolve_profile("shelf").unwrap().profile;
    assert_eq!(
        p.alarm_threshold(),
        0.5f64.next_up(),
        "back to the max rule"
    );
    let e = store
        .patch_thresholds(
            "shelf",
            ThresholdsPatch {
                e_b: Some(Some(f64::NAN)),
                ..Default::default()
            },
        )
        .unwrap_err();
    assert!(matches!(e, StoreError::Invalid { .. }), "{e}");
    assert!(serde_json::from_str::<ThresholdsPatch>(r#"{"e_x": 1}"#).is_err());

    // Non-finite calibrations are refused rather than stored as null.
    let mut bad = calibration(None);
    bad.score_max = f64::INFINITY;
    assert!(matches!(
        store.save_calibration("shelf", bad),
        Err(StoreError::Invalid { .. })
    ));
    assert!(matches!(
        store.save_calibration("ghost", calibration(None)),
        Err(StoreError::NotFound { .. })
    ));
}

#[test]
fn resolving_follows_the_active_model_and_warns_about_a_stale_calibration() {
    let dir = tempfile::tempdir().unwrap();
    let store = open(dir.path());
    let v1 = commit_model(&store, "m", b"model one");
    let v2 = commit_model(&store, "m", b"model two");
    let spec = ProfileSpec {
        model: Some(ModelRef {
            name: "m".into(),
            version: None,
        }),
        ..Default::default()
    };
    store.put_profile("p", spec).unwrap();
    store
        .save_calibration("p", calibration(Some(v1.sha256.clone())))
        .unwrap();
    let r = store.resolve_profile("p").unwrap();
    assert_eq!(
        r.model,
        Some(ResolvedModel {
            name: "m".into(),
            version: 1,
            sha256: v1.sha256.clone()
        })
    );
    assert_eq!(
        r.profile.file.model.as_deref(),
        Some(store.dir().join("models/m/1.vamos").as_path())
    );
    assert!(r.warnings.is_empty(), "{:?}", r.warnings);
    store.set_active_model("m", 2).unwrap();
    let r = store.resolve_profile("p").unwrap();
    assert_eq!(
        r.model.as_ref().map(|m| (m.version, m.sha256.as_str())),
        Some((2, v2.sha256.as_str()))
    );
    assert_eq!(
        std::fs::read(r.profile.file.model.unwrap()).unwrap(),
        b"model two"
    );
    assert_eq!(r.warnings.len(), 1);
    assert!(r.warnings[0].contains("m@2"), "{:?}", r.warnings);
}

#[test]
fn a_restart_finds_everything_as_it_was() {
    let dir = tempfile::tempdir().unwrap();
    let (models, robots, profiles) = {
        let store = open(dir.path());
        commit_model(&store, "m", b"one");
        commit_model(&store, "m", b"two");
        store.set_active_model("m", 2).unwrap();
        commit_urdf(&store, "arm");
        let spec = ProfileSpec {
            robot: Some("arm".into()),
            camera: Some(camera()),
            model: Some(ModelRef {
                name: "m".into(),
                version: Some(1),
            }),
            pipeline: Some(vamos_core::pipeline::PipelineConfig {
                stride: 3,
                ..Default::default()
            }),
            ..Default::default()
        };
        store.put_profile("p", spec).unwrap();
        store.save_calibration("p", calibration(None)).unwrap();
        store
            .patch_thresholds(
                "p",
                ThresholdsPatch {
                    e_b: Some(Some(0.125)),
                    ..Default::default()
                },
            )
            .unwrap();
        (store.models(), store.robots(), store.profiles())
    };
    let store = open(dir.path());
    assert_eq!(store.models(), models);
    assert_eq!(store.robots(), robots);
    assert_eq!(store.profiles(), profiles);
    assert_eq!(store.profiles()[0].thresholds.e_b, Some(0.125));
    assert_eq!(
        store.profiles()[0].spec.pipeline.as_ref().unwrap().stride,
        3
    );
    assert!(store.problems().is_empty(), "{:?}", store.problems());
    assert_eq!(
        store.open_report(),
        OpenReport {
            removed_temp_entries: 0,
            removed_orphan_files: 0,
            // index + 2 bundles, meta + URDF, profile + calibration
            verified_files: 7,
        }
    );
    // And the numbering goes on where it was.
    assert_eq!(commit_model(&store, "m", b"three").version, 3);
}

#[test]
fn the_directory_is_locked_while_open() {
    let dir = tempfile::tempdir().unwrap();
    let store = open(dir.path());
    let e = Store::open(dir.path(), StoreLimits::default()).unwrap_err();
    assert!(matches!(e, StoreError::Locked { .. }), "{e}");
    let clone = store.clone();
    drop(store);
    assert!(matches!(
        Store::open(dir.path(), StoreLimits::default()),
        Err(StoreError::Locked { .. })
    ));
    drop(clone);
    open(dir.path());
}

#[test]
fn leftovers_of_interrupted_uploads_and_writes_are_removed_on_open() {
    let dir = tempfile::tempdir().unwrap();
    {
        let store = open(dir.path());
        commit_model(&store, "m", b"kept");
        commit_urdf(&store, "arm");
        // An upload cut off by a crash: its file stays in tmp/.
        let mut u = store.begin_upload(UploadKind::Model).unwrap();
        u.write_chunk(b"half a bundle").unwrap();
        std::mem::forget(u);
        // A staging folder and a bundle renamed in but never recorded.
        std::fs::create_dir(store.dir().join("tmp/new-1-1")).unwrap();
        std::fs::write(store.dir().join("tmp/new-1-1/index.json"), "{}").unwrap();
        std::fs::write(store.dir().join("models/m/2.vamos"), b"orphan").unwrap();
        std::fs::write(store.dir().join("robots/arm/7.zip"), b"orphan").unwrap();
        // A file that is none of ours is left alone.
        std::fs::write(store.dir().join("models/m/notes.txt"), b"mine").unwrap();
        assert_eq!(entries(&store.dir().join("tmp")).len(), 2);
    }
    let store = open(dir.path());
    let report = store.open_report();
    assert_eq!(report.removed_temp_entries, 2);
    assert_eq!(report.removed_orphan_files, 2);
    assert!(entries(&store.dir().join("tmp")).is_empty());
    assert_eq!(
        entries(&store.dir().join("models/m")),
        ["1.vamos", "index.json", "notes.txt"]
    );
    assert_eq!(
        entries(&store.dir().join("robots/arm")),
        ["1.urdf", "meta.json"]
    );
    assert!(store.problems().is_empty(), "{:?}", store.problems());
    // The orphan's number was never recorded, so it is given again.
    assert_eq!(commit_model(&store, "m", b"second").version, 2);
}

fn flip_byte(path: &Path, at: usize) {
    let mut bytes = std::fs::read(path).unwrap();
    bytes[at] ^= 0x01;
    std::fs::write(path, bytes).unwrap();
}

#[test]
fn corrupt_files_are_reported_on_open_and_never_served() {
    let dir = tempfile::tempdir().unwrap();
    {
        let store = open(dir.path());
        commit_model(&store, "m", b"bundle one");
        commit_model(&store, "m", b"bundle two");
        commit_urdf(&store, "arm");
        commit_urdf(&store, "arm2");
        let spec = ProfileSpec {
            robot: Some("arm".into()),
            camera: Some(camera()),
            ..Default::default()
        };
        store.put_profile("p", spec).unwrap();
        store.save_calibration("p", calibration(None)).unwrap();
    }
    let d = dir.path();
    flip_byte(&d.join("models/m/1.vamos"), 3);
    flip_byte(&d.join("robots/arm/1.urdf"), 100);
    // Metadata: edit a value inside the body without fixing the checksum.
    let meta = std::fs::read_to_string(d.join("robots/arm2/meta.json")).unwrap();
    std::fs::write(
        d.join("robots/arm2/meta.json"),
        meta.replace("\"revision\": 1", "\"revision\": 2"),
    )
    .unwrap();
    let cal = std::fs::read_to_string(d.join("profiles/p/calibration.json")).unwrap();
    std::fs::write(
        d.join("profiles/p/calibration.json"),
        cal.replace("120", "121"),
    )
    .unwrap();

    let store = open(d);
    let problems = store.problems();
    let mut seen: Vec<(&str, &str)> = problems.iter().map(|p| (p.kind, p.name.as_str())).collect();
    seen.sort();
    assert_eq!(
        seen,
        [
            ("model version", "m@1"),
            ("profile", "p"),
            ("robot", "arm"),
            ("robot", "arm2")
        ],
        "{problems:?}"
    );
    assert!(
        problems.iter().all(|p| p.reason.contains("checksum")),
        "{problems:?}"
    );

    // The corrupt bundle is listed with its problem and refused; the other is served.
    let m = store.model("m").unwrap();
    assert!(m.versions[0].problem.is_some());
    assert!(m.versions[1].problem.is_none());
    let e = store.model_path("m", Some(1)).unwrap_err();
    assert!(matches!(e, StoreError::Corrupt { .. }), "{e}");
    assert_eq!(e.kind(), StoreErrorKind::Internal);
    assert!(
        matches!(store.model_path("m", None), Err(StoreError::Corrupt { .. })),
        "the active version is the corrupt one"
    );
    assert!(matches!(
        store.set_active_model("m", 1),
        Err(StoreError::Corrupt { .. })
    ));
    store.set_active_model("m", 2).unwrap();
    assert_eq!(store.model_path("m", None).unwrap().0, 2);

    // A robot whose file is damaged is listed but refused; one whose metadata is
    // damaged is quarantined: neither read nor replaced, only deleted.
    assert!(store.robot("arm").unwrap().problem.is_some());
    assert!(matches!(
        store.robot_path("arm"),
        Err(StoreError::Corrupt { .. })
    ));
    assert!(matches!(
        store.robot("arm2"),
        Err(StoreError::Corrupt { .. })
    ));
    assert_eq!(store.robots().len(), 1);
    let bytes = std::fs::read(fixture("sim/robot/vamos_arm.urdf")).unwrap();
    let u = upload(
        &store,
        UploadKind::Robot {
            format: RobotFormat::Urdf,
        },
        &bytes,
    );
    assert!(matches!(
        store.commit_robot("arm2", u, accept(json!(null))),
        Err(StoreError::Corrupt { .. })
    ));
    store.delete_robot("arm2").unwrap();
    assert!(!d.join("robots/arm2").exists());
    commit_urdf(&store, "arm2");

    // A profile whose calibration is damaged does not resolve (no silent loss of its
    // thresholds) until a calibration is saved again.
    assert!(store.profile("p").unwrap().problem.is_some());
    assert!(store.profile("p").unwrap().calibration.is_none());
    assert!(matches!(
        store.resolve_profile("p"),
        Err(StoreError::Corrupt { .. })
    ));
    // The robot it uses is damaged too: replace it, recalibrate, and it resolves.
    commit_urdf(&store, "arm");
    store.save_calibration("p", calibration(None)).unwrap();
    let r = store.resolve_profile("p").unwrap();
    assert_eq!(r.profile.thresholds().e_b, Some(3.25));
    let left: Vec<_> = store.problems().into_iter().map(|p| p.name).collect();
    assert_eq!(left, ["m@1"]);
}

#[test]
fn concurrent_commits_of_one_name_get_distinct_versions() {
    let dir = tempfile::tempdir().unwrap();
    let store = open(dir.path());
    let threads: Vec<_> = (0..8u8)
        .map(|i| {
            let store = store.clone();
            std::thread::spawn(move || {
                let payload = vec![i; 1000 + usize::from(i)];
                let u = upload(&store, UploadKind::Model, &payload);
                let info = store.commit_model("m", u, accept(json!({"i": i}))).unwrap();
                (info.version, sha256_hex(&payload))
            })
        })
        .collect();
    let mut got: Vec<(u32, String)> = threads.into_iter().map(|t| t.join().unwrap()).collect();
    got.sort();
    assert_eq!(
        got.iter().map(|(v, _)| *v).collect::<Vec<_>>(),
        (1..=8).collect::<Vec<_>>()
    );
    drop(store);
    let store = open(dir.path());
    let m = store.model("m").unwrap();
    for (v, sha) in &got {
        let stored = m.versions.iter().find(|s| s.version == *v).unwrap();
        assert_eq!(&stored.sha256, sha);
        let (_, path) = store.model_path("m", Some(*v)).unwrap();
        assert_eq!(&sha256_hex(&std::fs::read(path).unwrap()), sha);
    }
    assert!(store.problems().is_empty());
}

#[test]
fn job_records_survive_a_restart_and_a_running_one_is_marked_interrupted() {
    let dir = tempfile::tempdir().unwrap();
    let store = open(dir.path());
    let done = store
        .start_job("p", vec!["a.mcap".into()], Vec::new())
        .unwrap();
    assert_eq!(done.id, 1);
    assert_eq!(done.state, JobState::Running);
    let cal = calibration(None);
    let ended = store
        .finish_job(done.id, Ok((cal.clone(), vec!["note".into()])))
        .unwrap();
    assert_eq!(ended.state, JobState::Succeeded);
    assert!(ended.finished_unix_s.is_some());
    // Ending twice changes nothing.
    let again = store
        .finish_job(done.id, Err((JobState::Failed, "late".into())))
        .unwrap();
    assert_eq!(again, ended);
    let cancelled = store.start_job("p", Vec::new(), Vec::new()).unwrap();
    store
        .finish_job(cancelled.id, Err((JobState::Cancelled, "asked".into())))
        .unwrap();
    // A job still running when the server stops (a crash: the store is dropped).
    let running = store
        .start_job(
            "q",
            vec!["/data/x.mcap".into()],
            vec!["/data/h.mcap".into()],
        )
        .unwrap();
    assert!(matches!(
        store.delete_job(running.id),
        Err(StoreError::InUse { .. })
    ));
    drop(store);

    let store = open(dir.path());
    let jobs = store.jobs();
    assert_eq!(jobs.len(), 3);
    assert_eq!(jobs[0], ended);
    assert_eq!(jobs[0].calibration.as_ref(), Some(&cal));
    assert_eq!(jobs[1].state, JobState::Cancelled);
    let interrupted = &jobs[2];
    assert_eq!(interrupted.state, JobState::Failed);
    assert!(
        interrupted
            .error
            .as_deref()
            .is_some_and(|e| e.contains("interrupted")),
        "{interrupted:?}"
    );
    assert_eq!(interrupted.holdout, vec!["/data/h.mcap".to_string()]);
    // Ids go on after the largest kept; removing a record is durable.
    assert_eq!(store.start_job("p", Vec::new(), Vec::new()).unwrap().id, 4);
    store.delete_job(1).unwrap();
    assert!(matches!(store.job(1), Err(StoreError::NotFound { .. })));
    drop(store);
    let store = open(dir.path());
    assert_eq!(
        store.jobs().iter().map(|j| j.id).collect::<Vec<_>>(),
        vec![2, 3, 4]
    );
    // A damaged record is reported, not served.
    std::fs::write(dir.path().join("jobs/2.json"), b"{ nope").unwrap();
    drop(store);
    let store = open(dir.path());
    assert!(store.job(2).is_err());
    assert!(
        store
            .problems()
            .iter()
            .any(|p| p.kind == "job" && p.name == "2")
    );
}

/// Stages every file of `from` that `to` lacks, as a shared store's reader would.
fn stage_from(from: &Store, to: &Store) -> (Vec<StoredFile>, HashMap<String, PathBuf>) {
    let files = from.stored_files().unwrap();
    let mut staged = HashMap::new();
    for f in &files {
        let copy = to.dir().join("tmp").join(&f.sha256);
        std::fs::copy(from.dir().join(&f.path), &copy).unwrap();
        staged.insert(f.sha256.clone(), copy);
    }
    (files, staged)
}

/// The fleet test that lost a publication: `index.json` was replaced by content of the
/// same size (`"active": 1` -> `2`) within one tick of the file system's clock, so size
/// and modification time matched the cached hash, and the writer never saw the change.
#[test]
fn a_file_replaced_within_one_clock_tick_is_hashed_again() {
    let dir = tempfile::tempdir().unwrap();
    let store = open(dir.path());
    commit_model(&store, "m", b"v1");
    commit_model(&store, "m", b"v2");
    let index = dir.path().join("models/m/index.json");
    let sha_of = |files: &[StoredFile]| {
        files
            .iter()
            .find(|f| f.path == "models/m/index.json")
            .map(|f| (f.sha256.clone(), f.size))
            .unwrap()
    };
    let before = sha_of(&store.stored_files().unwrap());
    let stamp = std::fs::metadata(&index).unwrap().modified().unwrap();

    store.set_active_model("m", 2).unwrap();
    std::fs::File::options()
        .write(true)
        .open(&index)
        .unwrap()
        .set_modified(stamp)
        .unwrap();
    let after = sha_of(&store.stored_files().unwrap());
    assert_eq!(after.1, before.1, "the test needs content of the same size");
    assert_ne!(after.0, before.0, "a stale hash was listed");
    assert_eq!(after.0, files::hash_file(&index).unwrap().0);
}

#[test]
fn a_mirror_holds_exactly_what_was_published_and_refuses_changes() {
    let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let writer = open(a.path());
    let reader = open(b.path());
    reader.set_read_only(Some("send changes to the writer".into()));
    commit_urdf(&writer, "arm");
    commit_model(&writer, "m", b"v1");
    commit_model(&writer, "m", b"v2");
    let spec = ProfileSpec {
        robot: Some("arm".into()),
        camera: Some(camera()),
        model: Some(ModelRef {
            name: "m".into(),
            version: None,
        }),
        ..Default::default()
    };
    writer.put_profile("p", spec.clone()).unwrap();
    writer.save_calibration("p", calibration(None)).unwrap();

    let files = writer.stored_files().unwrap();
    let paths: Vec<&str> = files.iter().map(|f| f.path.as_str()).collect();
    assert_eq!(
        paths,
        [
            "models/m/1.vamos",
            "models/m/2.vamos",
            "models/m/index.json",
            "profiles/p/calibration.json",
            "profiles/p/profile.json",
            "robots/arm/1.urdf",
            "robots/arm/meta.json",
        ]
    );
    assert_eq!(files[0].sha256, sha256_hex(b"v1"));
    assert_eq!(files[0].size, 2);

    // A missing content changes nothing.
    let (files, mut staged) = stage_from(&writer, &reader);
    let kept = staged.remove(&sha256_hex(b"v2")).unwrap();
    let e = reader.apply_mirror(&files, &staged).unwrap_err();
    assert!(e.to_string().contains("models/m/2.vamos"), "{e}");
    assert!(reader.models().is_empty());
    staged.insert(sha256_hex(b"v2"), kept);
    let change = reader.apply_mirror(&files, &staged).unwrap();
    assert_eq!(change.written.len(), 7);
    assert!(change.removed.is_empty());
    assert_eq!(reader.stored_files().unwrap(), files);
    assert_eq!(reader.model("m").unwrap().active, Some(1));
    let resolved = reader.resolve_profile("p").unwrap();
    assert_eq!(resolved.profile.calibration.unwrap().training_frames, 120);
    assert!(reader.problems().is_empty(), "{:?}", reader.problems());

    // Every change is refused on the mirror, with the reason.
    let e = reader.put_profile("q", spec).unwrap_err();
    assert_eq!(e.kind(), StoreErrorKind::Conflict);
    assert!(e.to_string().contains("send changes to the writer"), "{e}");
    assert!(reader.begin_upload(UploadKind::Model).is_err());
    assert!(reader.delete_profile("p").is_err());
    assert!(reader.set_active_model("m", 1).is_err());

    // Deletes and new versions reach the mirror; unchanged files are not copied again.
    writer.delete_profile("p").unwrap();
    writer.delete_model("m", Some(2)).unwrap();
    let (files, staged) = stage_from(&writer, &reader);
    let change = reader.apply_mirror(&files, &staged).unwrap();
    assert_eq!(change.written, ["models/m/index.json"]);
    // Metadata goes first, so no folder ever names a file that is gone.
    assert_eq!(
        change.removed,
        [
            "profiles/p/calibration.json",
            "profiles/p/profile.json",
            "models/m/2.vamos"
        ]
    );
    assert_eq!(reader.stored_files().unwrap(), files);
    assert!(reader.profiles().is_empty());
    assert!(!b.path().join("profiles/p").exists());
    assert_eq!(reader.model("m").unwrap().active, Some(1));
    assert!(matches!(
        reader.model_path("m", Some(2)),
        Err(StoreError::NotFound { .. })
    ));
    let objects = change.objects();
    assert!(objects.contains(&("profiles".into(), "p".into())));
    assert!(objects.contains(&("models".into(), "m".into())));

    // Paths outside the data directory's objects are refused.
    for bad in [
        "../etc/passwd",
        "models/m/../../x",
        "jobs/1.json",
        "models/m",
        "tmp/a/b",
    ] {
        let listed = [StoredFile {
            path: bad.into(),
            sha256: sha256_hex(b"v1"),
            size: 2,
        }];
        let e = reader.apply_mirror(&listed, &HashMap::new()).unwrap_err();
        assert_eq!(e.kind(), StoreErrorKind::BadRequest, "{bad}: {e}");
    }
    reader.set_read_only(None);
    commit_model(&reader, "local", b"x");
}
