//! Robots: stored, replaced and loaded from their files.

use super::*;

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
