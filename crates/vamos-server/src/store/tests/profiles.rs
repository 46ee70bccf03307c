//! Profiles: references, protection, resolution with the active model and threshold overrides.

use super::*;

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
