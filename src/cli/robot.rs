//! `vamos robot inspect`: load a robot description and print what vamos sees in it as one
//! JSON object (names, joints, visuals, warnings; link poses for given joint positions).

use anyhow::{Context, Result};
use serde_json::{Map, Value, json};
use std::path::Path;
use std::path::PathBuf;
use vamos::config::Settings;
use vamos::robot::{Robot, RobotConfig};

#[derive(clap::Subcommand, Debug)]
pub enum Command {
    /// Load a robot and print its joints, links, visuals, warnings (and link poses for
    /// given joint positions) as one JSON object.
    Inspect {
        /// URDF file, robot package folder, or .zip / .tar.gz package archive.
        #[arg(long)]
        robot: PathBuf,
        /// JSON object of joint name -> position (rad or m): adds `poses` and
        /// `out_of_limits`.
        #[arg(long)]
        joints: Option<PathBuf>,
    },
}

/// Runs `vamos robot ...`.
pub fn run(settings: &Settings, command: Command) -> Result<()> {
    let Command::Inspect { robot, joints } = command;
    let out = inspect(&robot, joints.as_deref(), &settings.robot)?;
    println!("{out}");
    Ok(())
}

/// Loads `robot` (URDF file, package folder or archive); with `joints` (a JSON object of
/// joint name -> position), adds `poses` of every link in the root frame and
/// `out_of_limits`. Returns the JSON object to print.
pub fn inspect(robot: &Path, joints: Option<&Path>, cfg: &RobotConfig) -> Result<Value> {
    let r = Robot::load(robot, cfg)
        .with_context(|| format!("cannot load robot {}", robot.display()))?;
    let links = r.links();
    let joint_list: Vec<Value> = r
        .joints()
        .iter()
        .map(|j| {
            json!({
                "name": j.name,
                "type": j.kind,
                "parent": links[j.parent],
                "child": links[j.child],
                "axis": [j.axis.x, j.axis.y, j.axis.z],
                "limits": j.limits,
                "mimic": j.mimic.map(|m| json!({
                    "joint": r.joints()[m.joint].name,
                    "multiplier": m.multiplier,
                    "offset": m.offset,
                })),
            })
        })
        .collect();
    let link_list: Vec<Value> = links
        .iter()
        .enumerate()
        .map(|(i, name)| {
            let triangles: usize = r.visuals(i).iter().map(|v| v.triangles).sum();
            json!({ "name": name, "visuals": r.visuals(i), "triangles": triangles })
        })
        .collect();
    let mut out = json!({
        "robot": r.name(),
        "root": links[r.root()],
        "joints": joint_list,
        "links": link_list,
        "triangles": r.triangle_count(),
        "vertices": r.link_meshes().iter().map(|m| m.mesh.positions.len()).sum::<usize>(),
        "warnings": r.warnings(),
    });
    if let Some(path) = joints {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read {}", path.display()))?;
        let given: Map<String, Value> = serde_json::from_str(&text).with_context(|| {
            format!(
                "{} must be a JSON object of joint name -> position",
                path.display()
            )
        })?;
        let mut pairs = Vec::with_capacity(given.len());
        for (name, v) in &given {
            let value = v
                .as_f64()
                .with_context(|| format!("joint {name:?}: position {v} is not a number"))?;
            pairs.push((name.as_str(), value));
        }
        let mut mapper = r.joint_mapper();
        let mapped = mapper.map_pairs(pairs)?;
        let poses = r.forward(&mapped.positions)?;
        let mut pose_map = Map::new();
        for (name, pose) in links.iter().zip(&poses) {
            let t = pose.translation.vector;
            let q = pose.rotation.coords; // x, y, z, w
            pose_map.insert(
                name.clone(),
                json!({ "translation": [t.x, t.y, t.z], "rotation_xyzw": [q.x, q.y, q.z, q.w] }),
            );
        }
        out["poses"] = Value::Object(pose_map);
        out["out_of_limits"] = json!(r.out_of_limits(&mapped.positions));
        out["unknown_joints"] = json!(mapped.unknown);
        out["missing_joints"] = json!(mapped.missing);
    }
    Ok(out)
}
