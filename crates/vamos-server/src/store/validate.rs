//! Ready-made validators for [`super::Store::commit_model`] and
//! [`super::Store::commit_robot`]: they load the upload the way serving will and return
//! a summary to record.

use serde_json::json;
use std::path::Path;
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
