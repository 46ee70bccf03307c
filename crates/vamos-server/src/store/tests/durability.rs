//! The data directory across restarts: locking, leftovers of interrupted writes, corrupt files, job records.

use super::*;

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
