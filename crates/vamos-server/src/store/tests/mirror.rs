//! The fleet mirror: the published file list, its hash cache, applying a publication.

use super::*;

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
