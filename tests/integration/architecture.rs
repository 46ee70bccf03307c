//! Keeps the dependency direction of ARCHITECTURE.md true by scanning `use` lines:
//! the core never reaches for async/network crates, and a core module imports only the
//! vamos modules below it.

use std::path::{Path, PathBuf};

/// Core modules in dependency order: each may import only the ones before it. `eval`
/// (evaluation and calibration maths) comes first: a leaf that imports no vamos module.
const CORE: &[&str] = &["eval", "vision", "robot", "model", "episode", "pipeline"];
/// Crates the core must not use (the service layer's business).
const FORBIDDEN: &[&str] = &["tokio", "tonic", "prost", "axum", "http", "hyper", "tower"];
/// Core files allowed one forbidden crate, and why: the ONNX model file is protobuf, so
/// its reader decodes with prost (a file codec there, not a transport).
const CORE_EXCEPTIONS: &[(&str, &str)] = &[("model/onnx_proto.rs", "prost")];

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

#[test]
fn core_modules_respect_the_dependency_direction() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
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
            let rel = file
                .strip_prefix(&src)
                .unwrap()
                .to_string_lossy()
                .replace('\\', "/");
            for root in referenced_roots(&text) {
                let excepted = CORE_EXCEPTIONS.contains(&(rel.as_str(), root.as_str()));
                assert!(
                    excepted || !FORBIDDEN.contains(&root.as_str()),
                    "{} (core module `{module}`) uses `{root}`",
                    file.display()
                );
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
        checked >= 5,
        "expected to scan the vision sources, scanned {checked} files"
    );
}

#[test]
fn eval_is_a_leaf() {
    let mut files = Vec::new();
    rust_files(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("src/eval"),
        &mut files,
    );
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
        &["tonic", "prost", "axum", "http", "hyper", "tower"],
        &["api", "service", "client", "fuzz"],
    ),
    ("api", &[], &["service", "client", "fuzz"]),
];

#[test]
fn the_session_layer_speaks_core_types_and_the_edge_points_down() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
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
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    rust_files(&src.join("config"), &mut files);
    assert!(!files.is_empty(), "expected the config sources");
    for file in files {
        let text = std::fs::read_to_string(&file).unwrap();
        for root in referenced_roots(&text) {
            if let Some(m) = root.strip_prefix("crate::") {
                assert!(
                    !["service", "session", "api", "client"].contains(&m),
                    "{} imports `crate::{m}`: settings sit below the server",
                    file.display()
                );
            }
        }
    }
}
