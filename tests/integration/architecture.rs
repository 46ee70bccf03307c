//! Keeps the dependency direction of ARCHITECTURE.md true where Cargo does not: the
//! kernel and core crates name no async or transport crate in their manifests, a core
//! module imports only the core modules below it, and the service's edge points down.

use std::path::{Path, PathBuf};

/// The core crate's modules (crates/vamos-core) in dependency order: each may import only
/// the ones before it. `eval` (evaluation and calibration maths) comes first: a leaf that
/// imports no vamos module. Between crates Cargo keeps the direction (a crate can import
/// only the crates its Cargo.toml names: the kernel crates and the core name no async or
/// transport crate); inside one crate this scan does.
const CORE: &[&str] = &["eval", "episode", "pipeline", "setup"];

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let p = e.path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// Every `use` / path mention of a top-level crate or `crate::` module in `src`.
fn referenced_roots(src: &str) -> Vec<String> {
    let mut roots = Vec::new();
    for line in src.lines() {
        let l = line.trim_start();
        if l.starts_with("//") {
            continue;
        }
        for token in l.split(|c: char| !(c.is_alphanumeric() || c == '_' || c == ':')) {
            if let Some(rest) = token.strip_prefix("crate::") {
                roots.push(format!("crate::{}", rest.split("::").next().unwrap_or("")));
            } else if let Some((head, _)) = token.split_once("::") {
                roots.push(head.to_string());
            }
        }
    }
    roots
}

/// The crates below the server, and the crates none of them may depend on (the service
/// layer's business).
const BELOW_THE_SERVER: &[&str] = &["vamos-vision", "vamos-robot", "vamos-model", "vamos-core"];
const FORBIDDEN: &[&str] = &[
    "tokio",
    "tonic",
    "prost-types",
    "axum",
    "http",
    "hyper",
    "tower",
    "vamos",
];

/// The package names of a manifest's `[dependencies]` section.
fn dependencies(manifest: &str) -> Vec<String> {
    let mut names = Vec::new();
    let mut inside = false;
    for line in manifest.lines() {
        let l = line.trim();
        if l.starts_with('[') {
            inside = l == "[dependencies]";
        } else if inside && !l.is_empty() && !l.starts_with('#') {
            let name = l.split(['=', '.', ' ']).next().unwrap_or("");
            names.push(name.to_string());
        }
    }
    names
}

#[test]
fn the_kernel_and_core_crates_name_no_server_crate() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    for krate in BELOW_THE_SERVER {
        let manifest =
            std::fs::read_to_string(root.join("crates").join(krate).join("Cargo.toml")).unwrap();
        let deps = dependencies(&manifest);
        assert!(
            deps.len() >= 5,
            "{krate}: expected its dependencies, read {deps:?}"
        );
        for d in &deps {
            assert!(
                !FORBIDDEN.contains(&d.as_str()),
                "{krate} depends on `{d}`, a server crate"
            );
        }
    }
    let probe =
        dependencies("[dependencies]\ntokio.workspace = true\n\n[dev-dependencies]\naxum = \"1\"");
    assert_eq!(
        probe,
        ["tokio"],
        "the manifest reader sees a dependency and stops at the next section"
    );
}

fn server_src() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("crates/vamos-server/src")
}

fn core_src() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("crates/vamos-core/src")
}

#[test]
fn core_modules_respect_the_dependency_direction() {
    let src = core_src();
    let mut checked = 0;
    for (i, module) in CORE.iter().enumerate() {
        let mut files = Vec::new();
        rust_files(&src.join(module), &mut files);
        let single = src.join(format!("{module}.rs"));
        if single.is_file() {
            files.push(single);
        }
        for file in files {
            let text = std::fs::read_to_string(&file).unwrap();
            for root in referenced_roots(&text) {
                if let Some(m) = root.strip_prefix("crate::") {
                    assert!(
                        m.is_empty() || CORE[..=i].contains(&m),
                        "{} (core module `{module}`) imports `crate::{m}`, which is above it",
                        file.display()
                    );
                }
            }
            checked += 1;
        }
    }
    assert!(
        checked >= 20,
        "expected to scan the core's sources, scanned {checked} files"
    );
}

#[test]
fn eval_is_a_leaf() {
    let mut files = Vec::new();
    rust_files(&core_src().join("eval"), &mut files);
    assert!(
        files.len() >= 5,
        "expected the eval sources, found {files:?}"
    );
    for file in files {
        let text = std::fs::read_to_string(&file).unwrap();
        for root in referenced_roots(&text) {
            if let Some(m) = root.strip_prefix("crate::") {
                assert!(
                    m.is_empty() || m == "eval",
                    "{} imports `crate::{m}`; eval must not depend on other vamos modules",
                    file.display()
                );
            }
            assert!(
                !root.starts_with("vamos_"),
                "{} uses `{root}`; eval must not depend on other vamos crates",
                file.display()
            );
        }
    }
}

#[test]
fn the_scanner_sees_violations() {
    let roots = referenced_roots(
        "use tokio::sync::mpsc;\nlet x = crate::api::grpc::f();\n// use axum::Router;",
    );
    assert!(roots.contains(&"tokio".to_string()));
    assert!(roots.contains(&"crate::api".to_string()));
    assert!(!roots.contains(&"axum".to_string()), "comments are skipped");
}

/// Modules of the service's edge, bottom up: the session layer speaks core types only
/// (no transport crate), the transports (`api`) sit on it, the server on them.
const EDGE: &[(&str, &[&str], &[&str])] = &[
    (
        "session",
        &[
            "tonic",
            "prost",
            "axum",
            "http",
            "hyper",
            "tower",
            "vamos_proto",
        ],
        &["api", "service"],
    ),
    ("api", &[], &["service"]),
];

#[test]
fn the_session_layer_speaks_core_types_and_the_edge_points_down() {
    let src = server_src();
    for (module, crates, above) in EDGE {
        let mut files = Vec::new();
        rust_files(&src.join(module), &mut files);
        assert!(
            files.len() >= 5,
            "expected the {module} sources, found {files:?}"
        );
        for file in files {
            let text = std::fs::read_to_string(&file).unwrap();
            for root in referenced_roots(&text) {
                assert!(
                    !crates.contains(&root.as_str()),
                    "{} (module `{module}`) uses `{root}`",
                    file.display()
                );
                if let Some(m) = root.strip_prefix("crate::") {
                    assert!(
                        !above.contains(&m),
                        "{} (module `{module}`) imports `crate::{m}`, which is above it",
                        file.display()
                    );
                }
            }
        }
    }
}

#[test]
fn config_does_not_import_the_server() {
    let src = server_src();
    let mut files = Vec::new();
    rust_files(&src.join("config"), &mut files);
    assert!(!files.is_empty(), "expected the config sources");
    for file in files {
        let text = std::fs::read_to_string(&file).unwrap();
        for root in referenced_roots(&text) {
            if let Some(m) = root.strip_prefix("crate::") {
                assert!(
                    !["service", "session", "api", "store"].contains(&m),
                    "{} imports `crate::{m}`: settings sit below the server",
                    file.display()
                );
            }
        }
    }
}
