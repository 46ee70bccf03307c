//! Ready-made validators for [`super::Store::commit_model`] and
//! [`super::Store::commit_robot`]: they load the upload the way serving will and return
//! a summary to record.

use serde_json::json;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};
use vamos_model::Bundle;
use vamos_robot::{JointKind, Robot, RobotConfig};

/// Reads the file as a model bundle (`Bundle::read`: the zip, its manifest, the members'
/// checksums) and summarises it: `name`, `created`, `parameters_inference`, and the whole
/// `manifest`. No ONNX Runtime is needed.
pub fn model_bundle_summary(path: &Path) -> Result<serde_json::Value, String> {
    let bundle = Bundle::read(path).map_err(|e| format!("not a valid model bundle: {e}"))?;
    let m = &bundle.manifest;
    Ok(json!({
        "name": m.name,
        "created": m.created,
        "parameters_inference": m.architecture.parameters_inference,
        "manifest": serde_json::to_value(m).map_err(|e| e.to_string())?,
    }))
}

/// The summary [`model_bundle_summary`] makes, from a bundle's whole manifest (as
/// `vamos model inspect` prints it).
fn summary_of_manifest(manifest: serde_json::Value) -> serde_json::Value {
    json!({
        "name": manifest["name"],
        "created": manifest["created"],
        "parameters_inference": manifest["architecture"]["parameters_inference"],
        "manifest": manifest,
    })
}

/// Validates uploaded model bundles as serving will load them, in a child process
/// (`vamos model inspect`, one replica, one thread) under a data-segment limit
/// (`RLIMIT_DATA`: heap, private mappings, thread stacks) and a time limit, so that a
/// hostile bundle (a graph that asks for gigabytes when ONNX Runtime builds it, a zip
/// bomb) fails cleanly and the server's memory never holds it. Without a `vamos`
/// executable (a server started in-process by another program) it validates in the
/// server's process, unbounded, as [`Self::in_process`] says.
#[derive(Debug, Clone)]
pub struct ModelValidator {
    exe: Option<PathBuf>,
    memory_bytes: u64,
    timeout: Duration,
    model: vamos_model::ModelConfig,
}

impl ModelValidator {
    /// Validation by `exe` (else in this process) within `memory_bytes` and `timeout`,
    /// with the `[model]` settings `model`.
    pub fn new(
        exe: Option<PathBuf>,
        memory_bytes: u64,
        timeout: Duration,
        model: vamos_model::ModelConfig,
    ) -> Self {
        Self {
            exe,
            memory_bytes,
            timeout,
            model,
        }
    }

    /// Whether bundles are validated in the server's own process (no executable).
    pub fn in_process(&self) -> bool {
        self.exe.is_none()
    }

    /// Validates the bundle at `path` and summarises it as [`model_bundle_summary`]
    /// does; `Err` says why it is refused. Blocking.
    pub fn check(&self, path: &Path) -> Result<serde_json::Value, String> {
        let Some(exe) = &self.exe else {
            let summary = model_bundle_summary(path)?;
            let options = vamos_model::LoadOptions {
                replicas: 1,
                intra_threads: 1,
                ..self.model.load_options()
            };
            vamos_model::FlowModel::load(path, &options)
                .map_err(|e| format!("the model does not load with ONNX Runtime: {e}"))?;
            return Ok(summary);
        };
        let mut cmd = std::process::Command::new(exe);
        cmd.args(["model", "inspect"])
            .arg(path)
            .stdin(std::process::Stdio::null())
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::null());
        // The server's [model] settings, one replica and one thread as serving's first.
        if let Ok(serde_json::Value::Object(model)) = serde_json::to_value(&self.model) {
            for (key, value) in model {
                let value = match value {
                    serde_json::Value::String(s) => s,
                    serde_json::Value::Number(n) => n.to_string(),
                    serde_json::Value::Bool(b) => b.to_string(),
                    _ => continue,
                };
                cmd.env(format!("VAMOS_MODEL__{}", key.to_ascii_uppercase()), value);
            }
        }
        cmd.env("VAMOS_MODEL__REPLICAS", "1")
            .env("VAMOS_MODEL__THREADS", "1")
            .env("VAMOS_LOG__LEVEL", "error");
        limit_data(&mut cmd, self.memory_bytes);
        let mut child = cmd
            .spawn()
            .map_err(|e| format!("cannot start the model validation ({}): {e}", exe.display()))?;
        let mut stdout = child.stdout.take();
        let reader = std::thread::spawn(move || {
            let mut out = Vec::new();
            if let Some(s) = stdout.as_mut() {
                // At most 1 MiB of report (a manifest is at most 1 MiB).
                let _ = std::io::Read::read_to_end(&mut std::io::Read::take(s, 2 << 20), &mut out);
            }
            out
        });
        let deadline = Instant::now() + self.timeout;
        let status = loop {
            match child.try_wait() {
                Ok(Some(status)) => break status,
                Ok(None) if Instant::now() >= deadline => {
                    let _ = child.kill();
                    let _ = child.wait();
                    let _ = reader.join();
                    return Err(format!(
                        "the model's validation took longer than {:.0} s \
                         ([service] model_validation_s)",
                        self.timeout.as_secs_f64()
                    ));
                }
                Ok(None) => std::thread::sleep(Duration::from_millis(20)),
                Err(e) => return Err(format!("the model validation failed: {e}")),
            }
        };
        let out = reader.join().unwrap_or_default();
        let report: serde_json::Value = serde_json::from_slice(&out).unwrap_or_default();
        if status.success() && report["valid"] == true {
            return Ok(summary_of_manifest(report["manifest"].clone()));
        }
        match report["error"].as_str() {
            Some(e) => Err(format!("not a valid model bundle: {e}")),
            // No report: the validation died (an allocation past the limit aborts it).
            None => Err(format!(
                "the model's validation needed more than {} MiB or failed ({status}) \
                 ([service] model_validation_mb)",
                self.memory_bytes >> 20
            )),
        }
    }
}

/// Sets the child's `RLIMIT_DATA` to `bytes` (at most the limit the server itself runs
/// under) before it runs (Linux and other Unixes).
#[cfg(unix)]
fn limit_data(cmd: &mut std::process::Command, bytes: u64) {
    use std::os::unix::process::CommandExt;
    // SAFETY: getrlimit and setrlimit are async-signal-safe; the closure allocates
    // nothing and touches no lock, as pre_exec requires.
    unsafe {
        cmd.pre_exec(move || {
            let mut current = libc::rlimit {
                rlim_cur: 0,
                rlim_max: 0,
            };
            if libc::getrlimit(libc::RLIMIT_DATA, &mut current) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            // A hard limit can be lowered, never raised.
            let bytes = (bytes as libc::rlim_t).min(current.rlim_max);
            let limit = libc::rlimit {
                rlim_cur: bytes,
                rlim_max: bytes,
            };
            if libc::setrlimit(libc::RLIMIT_DATA, &limit) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
}

#[cfg(not(unix))]
fn limit_data(_: &mut std::process::Command, _: u64) {}

/// Loads the file as a robot (`Robot::load` with `cfg`, which dispatches on the
/// extension) and summarises it: the URDF's `robot_name`, `links`, `joints`,
/// `movable_joints` (names) and the loader's `warnings`.
pub fn robot_summary(path: &Path, cfg: &RobotConfig) -> Result<serde_json::Value, String> {
    let robot = Robot::load_stored(path, cfg).map_err(|e| format!("not a loadable robot: {e}"))?;
    let outside = robot.meshes_outside_package();
    if !outside.is_empty() {
        return Err(format!(
            "mesh paths outside the robot package are refused (a stored robot reads meshes \
             only from its own package; upload a zip or tar.gz with the meshes inside and \
             relative or package:// paths): {}",
            outside.join(", ")
        ));
    }
    let movable: Vec<&str> = robot
        .joints()
        .iter()
        .filter(|j| {
            matches!(
                j.kind,
                JointKind::Revolute | JointKind::Continuous | JointKind::Prismatic
            )
        })
        .map(|j| j.name.as_str())
        .collect();
    Ok(json!({
        "robot_name": robot.name(),
        "links": robot.links().len(),
        "joints": robot.joints().len(),
        "movable_joints": movable,
        "warnings": robot.warnings(),
    }))
}
