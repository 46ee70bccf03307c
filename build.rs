//! Build-time code generation: the list of `vamos demo`'s embedded assets (every file
//! under `assets/demo`, made by `assets/demo/make_demo_assets.sh`), as `include_bytes!`
//! entries. (The gRPC code is generated in crates/vamos-proto, the ONNX schema's in
//! crates/vamos-model.)

use std::path::{Path, PathBuf};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    demo_assets(&PathBuf::from(std::env::var("OUT_DIR")?))
}

/// Writes `demo_assets.rs`: `&[(relative path, bytes)]` of the files under `assets/demo`
/// that the demo uses (the generator script and its notes stay out of the binary).
fn demo_assets(out: &Path) -> Result<(), Box<dyn std::error::Error>> {
    let root = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR")?).join("assets/demo");
    println!("cargo:rerun-if-changed={}", root.display());
    let mut files = Vec::new();
    collect(&root, &root, &mut files)?;
    files.sort();
    let mut code = String::from("&[\n");
    for rel in &files {
        let abs = root.join(rel);
        println!("cargo:rerun-if-changed={}", abs.display());
        code.push_str(&format!(
            "    ({:?}, include_bytes!({:?}) as &[u8]),\n",
            rel.replace('\\', "/"),
            abs.display().to_string()
        ));
    }
    code.push(']');
    std::fs::write(out.join("demo_assets.rs"), code)?;
    Ok(())
}

fn collect(
    root: &Path,
    dir: &Path,
    files: &mut Vec<String>,
) -> Result<(), Box<dyn std::error::Error>> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Ok(());
    };
    for entry in entries {
        let path = entry?.path();
        if path.is_dir() {
            println!("cargo:rerun-if-changed={}", path.display());
            collect(root, &path, files)?;
        } else {
            let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("");
            let skip = name.ends_with(".sh") || name.ends_with(".md") || name.starts_with('.');
            if !skip {
                files.push(path.strip_prefix(root)?.to_string_lossy().into_owned());
            }
        }
    }
    Ok(())
}
