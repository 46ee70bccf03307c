//! `vamos model ...`: inspect a bundle, locate (or provision) ONNX Runtime.

use anyhow::Result;
use anyhow::bail;
use serde_json::json;
use std::path::Path;
use std::path::PathBuf;
use std::time::Instant;
use vamos::config::Settings;
use vamos::model::bundle::Bundle;
use vamos::model::runtime;
use vamos::model::{FlowModel, ModelConfig};

#[derive(clap::Subcommand, Debug)]
pub enum Command {
    /// Read and validate a model bundle (.vamos); print its summary as JSON (exit code 1
    /// when invalid).
    Inspect {
        /// The bundle.
        bundle: PathBuf,
    },
    /// Find (or download into the cache) and load ONNX Runtime; print where from as JSON.
    Runtime,
}

/// Runs `vamos model ...`.
pub fn run(settings: &Settings, command: Command) -> Result<()> {
    match command {
        Command::Inspect { bundle } => {
            if inspect(&bundle, &settings.model)? {
                Ok(())
            } else {
                bail!("{} is not a valid model bundle", bundle.display())
            }
        }
        Command::Runtime => runtime(&settings.model),
    }
}

/// Prints the manifest summary and the validation result of a bundle as one JSON object.
/// Returns whether the bundle is valid (the caller maps `false` to a failing exit code).
pub fn inspect(path: &Path, config: &ModelConfig) -> Result<bool> {
    let mut out = json!({ "path": path.display().to_string() });
    let bundle = match Bundle::read(path) {
        Ok(b) => b,
        Err(e) => {
            out["valid"] = json!(false);
            out["error"] = json!(e.to_string());
            println!("{}", serde_json::to_string_pretty(&out)?);
            return Ok(false);
        }
    };
    let m = &bundle.manifest;
    out["sha256"] = json!(bundle.sha256);
    out["manifest"] = serde_json::to_value(m)?;
    out["members"] = json!({
        "encoder.onnx": {"bytes": bundle.encoder.len()},
        "head.onnx": {"bytes": bundle.head.len()},
    });
    let start = Instant::now();
    let valid = match FlowModel::from_bundle(bundle, &config.load_options()) {
        Ok(model) => {
            out["valid"] = json!(true);
            out["dims"] = json!(model.dims());
            let (head, why) = model.head_backend();
            out["head"] = json!({ "backend": head, "note": why });
            out["load_ms"] = json!(start.elapsed().as_secs_f64() * 1e3);
            true
        }
        Err(e) => {
            out["valid"] = json!(false);
            out["error"] = json!(e.to_string());
            false
        }
    };
    println!("{}", serde_json::to_string_pretty(&out)?);
    Ok(valid)
}

/// Finds (or provisions) and loads ONNX Runtime; prints where it came from as JSON.
pub fn runtime(config: &ModelConfig) -> Result<()> {
    let rt = runtime::ensure(config.runtime_options())?;
    println!(
        "{}",
        json!({
            "path": rt.path.display().to_string(),
            "source": rt.source,
            "setup_secs": rt.setup_secs,
            "version": runtime::ORT_VERSION,
        })
    );
    Ok(())
}
