//! The fuzz targets' committed inputs, run as ordinary tests: every seed of
//! `fuzz/corpus/<target>/` and every input that once crashed a target
//! (`fuzz/regressions/<target>/`) goes through the target's `vamos::fuzz` function, so a
//! fixed crash stays fixed without a fuzzer installed. `cargo fuzz` runs the same
//! functions on mutated inputs (fuzz/README.md).

use std::path::{Path, PathBuf};

type Target = fn(&[u8]);

const TARGETS: [(&str, Target); 10] = [
    ("cdr_message", vamos::fuzz::cdr_message),
    ("mcap_episode", vamos::fuzz::mcap_episode),
    ("image_message", vamos::fuzz::image_message),
    ("urdf", vamos::fuzz::urdf),
    ("robot_archive", vamos::fuzz::robot_archive),
    ("mesh", vamos::fuzz::mesh),
    ("model_bundle", vamos::fuzz::model_bundle),
    ("stream_requests", vamos::fuzz::stream_requests),
    ("stream_session", vamos::fuzz::stream_session),
    ("rest_body", vamos::fuzz::rest_body),
];

fn fuzz_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("fuzz")
}

fn inputs(dir: &Path) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut files: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file())
        .collect();
    files.sort();
    files
}

#[test]
fn every_target_has_a_fuzz_binary_and_seeds() {
    let mut names: Vec<String> = std::fs::read_dir(fuzz_dir().join("fuzz_targets"))
        .unwrap()
        .map(|e| {
            let p = e.unwrap().path();
            p.file_stem().unwrap().to_string_lossy().into_owned()
        })
        .collect();
    names.sort();
    let mut listed: Vec<String> = TARGETS.iter().map(|t| t.0.to_string()).collect();
    listed.sort();
    assert_eq!(
        names, listed,
        "fuzz/fuzz_targets and this test's list differ"
    );
    let manifest = std::fs::read_to_string(fuzz_dir().join("Cargo.toml")).unwrap();
    for (name, _) in TARGETS {
        assert!(
            manifest.contains(&format!("name = \"{name}\"")),
            "{name} is not a [[bin]] of fuzz/Cargo.toml"
        );
        let seeds = inputs(&fuzz_dir().join("corpus").join(name));
        assert!(seeds.len() >= 3, "{name}: {} seeds", seeds.len());
    }
}

#[test]
fn seeds_and_past_crashes_run_clean() {
    let mut ran = 0;
    for (name, target) in TARGETS {
        for dir in ["corpus", "regressions"] {
            for input in inputs(&fuzz_dir().join(dir).join(name)) {
                let bytes = std::fs::read(&input).unwrap();
                // A panic here names the input: rerun it with `cargo fuzz run <target> FILE`.
                eprintln!("{name}: {}", input.display());
                target(&bytes);
                ran += 1;
            }
        }
    }
    assert!(ran >= 40, "only {ran} inputs");
}

/// The first crash the `mesh` target found: mesh-loader 0.1 indexes past a COLLADA
/// file's positions and panics. vamos reports it as this mesh's error.
#[test]
fn a_collada_index_past_its_positions_is_a_mesh_error() {
    let bytes =
        std::fs::read(fuzz_dir().join("regressions/mesh/collada-index-past-positions")).unwrap();
    let cfg = vamos::robot::RobotConfig::default();
    // The file as the target gets it: its first byte picks the format (2: COLLADA).
    assert_eq!(bytes[0] % 3, 2);
    let err = vamos::robot::mesh::mesh_from_bytes(&bytes[1..], Path::new("m.dae"), [1.0; 3], &cfg)
        .unwrap_err();
    assert!(
        matches!(err, vamos::robot::RobotError::MeshUnreadable { .. }),
        "{err}"
    );
    assert!(err.to_string().contains("malformed mesh"), "{err}");
}
