//! Model versions: numbering, the active version, validation, upload limits, names, concurrent commits.

use super::*;

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
