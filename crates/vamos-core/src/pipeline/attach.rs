//! Shapes a profile attaches to the robot's links: what the robot carries or wears that
//! its URDF does not describe (a grasped object, a tool). They are rendered with the body,
//! so they are masked out of the scene residual and moved with their link like the body.
//!
//! ```toml
//! [[pipeline.attach]]
//! link = "tool_link"
//! box = [0.17, 0.045, 0.24]      # or cylinder = { radius = 0.03, length = 0.2 }, sphere = 0.05
//! xyz = [0.0, 0.0, 0.09]         # the shape's centre in the link frame, metres
//! rpy = [0.0, 0.0, 0.0]          # its orientation, radians (URDF convention)
//! ```

use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use serde::{Deserialize, Serialize};
use vamos_robot::Robot;
use vamos_robot::geometry::{LinkMesh, TriMesh};
use vamos_robot::mesh::{box_mesh, cylinder_mesh, sphere_mesh};

/// One attached shape.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Attachment {
    /// The link it moves with.
    pub link: String,
    /// A box of this size (x, y, z), metres.
    #[serde(default, rename = "box", skip_serializing_if = "Option::is_none")]
    pub cuboid: Option<[f64; 3]>,
    /// A cylinder along the shape's z axis.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cylinder: Option<Cylinder>,
    /// A sphere of this radius, metres.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sphere: Option<f64>,
    /// The shape's centre in the link frame, metres.
    #[serde(default)]
    pub xyz: [f64; 3],
    /// The shape's orientation in the link frame, roll-pitch-yaw radians.
    #[serde(default)]
    pub rpy: [f64; 3],
}

/// A cylinder's size.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Cylinder {
    /// Radius, metres.
    pub radius: f64,
    /// Length along z, metres.
    pub length: f64,
}

/// Largest side or radius an attached shape may have, metres.
pub const MAX_SHAPE_M: f64 = 10.0;

impl Attachment {
    /// The shape's mesh in its own frame, or why it has none: exactly one of box,
    /// cylinder and sphere, every size finite, positive and at most [`MAX_SHAPE_M`].
    pub fn mesh(&self) -> Result<TriMesh, String> {
        let ok = |v: f64| v.is_finite() && v > 0.0 && v <= MAX_SHAPE_M;
        let shape = match (&self.cuboid, &self.cylinder, &self.sphere) {
            (Some(size), None, None) if size.iter().all(|&v| ok(v)) => box_mesh(*size),
            (None, Some(c), None) if ok(c.radius) && ok(c.length) => {
                cylinder_mesh(c.radius, c.length, 24)
            }
            (None, None, Some(r)) if ok(*r) => sphere_mesh(*r, 12),
            (None, None, None) => return Err("no shape (box, cylinder or sphere)".into()),
            (a, b, c)
                if [a.is_some(), b.is_some(), c.is_some()]
                    .iter()
                    .filter(|&&x| x)
                    .count()
                    > 1 =>
            {
                return Err("more than one shape (give one of box, cylinder, sphere)".into());
            }
            _ => {
                return Err(format!(
                    "sizes must be finite, positive and at most {MAX_SHAPE_M} m"
                ));
            }
        };
        if !self.xyz.iter().chain(&self.rpy).all(|v| v.is_finite()) {
            return Err("xyz and rpy must be finite".into());
        }
        let pose = Isometry3::from_parts(
            Translation3::new(self.xyz[0] as f32, self.xyz[1] as f32, self.xyz[2] as f32),
            UnitQuaternion::from_euler_angles(
                self.rpy[0] as f32,
                self.rpy[1] as f32,
                self.rpy[2] as f32,
            ),
        );
        let mut mesh = TriMesh::default();
        mesh.append_transformed(&shape, &pose);
        Ok(mesh)
    }
}

/// The robot's meshes with the attached shapes added. A shape on a link the robot does
/// not have, or with a bad size, is left out with a warning (returned, and logged): the
/// profile keeps working with the body it has.
pub fn meshes_with_attachments(
    robot: &Robot,
    attachments: &[Attachment],
) -> (Vec<LinkMesh>, Vec<String>) {
    let mut meshes = robot.link_meshes().to_vec();
    let mut warnings = Vec::new();
    for (i, a) in attachments.iter().enumerate() {
        let Some(link) = robot.kinematics().link_index(&a.link) else {
            warnings.push(format!(
                "attach[{i}]: the robot has no link {:?}; shape left out",
                a.link
            ));
            continue;
        };
        match a.mesh() {
            Ok(mesh) => meshes.push(LinkMesh { link, mesh }),
            Err(e) => warnings.push(format!("attach[{i}] on {:?}: {e}; shape left out", a.link)),
        }
    }
    for w in &warnings {
        tracing::warn!("{w}");
    }
    (meshes, warnings)
}

#[cfg(test)]
mod tests {
    use super::*;
    use vamos_robot::RobotConfig;

    const URDF: &str = r#"<robot name="r">
      <link name="base"><visual><geometry><box size="0.1 0.1 0.1"/></geometry></visual></link>
      <link name="tool"/>
      <joint name="j" type="revolute"><parent link="base"/><child link="tool"/>
        <axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
    </robot>"#;

    fn book(link: &str) -> Attachment {
        Attachment {
            link: link.into(),
            cuboid: Some([0.17, 0.045, 0.24]),
            cylinder: None,
            sphere: None,
            xyz: [0.0, 0.0, 0.09],
            rpy: [0.0, 0.0, 0.0],
        }
    }

    #[test]
    fn a_shape_moves_with_its_link_and_bad_ones_are_left_out_with_a_reason() {
        let robot = Robot::from_urdf_str(URDF, None, &RobotConfig::default()).unwrap();
        let base = robot.link_meshes().len();
        let (meshes, warnings) = meshes_with_attachments(&robot, &[book("tool")]);
        assert!(warnings.is_empty(), "{warnings:?}");
        assert_eq!(meshes.len(), base + 1);
        let added = meshes.last().unwrap();
        assert_eq!(added.link, robot.kinematics().link_index("tool").unwrap());
        let zs: Vec<f32> = added.mesh.positions.iter().map(|p| p.z).collect();
        let (lo, hi) = zs
            .iter()
            .fold((f32::MAX, f32::MIN), |(a, b), &z| (a.min(z), b.max(z)));
        assert!(
            (lo + 0.03).abs() < 1e-5 && (hi - 0.21).abs() < 1e-5,
            "{lo} {hi}"
        );

        let mut two = book("tool");
        two.sphere = Some(0.1);
        let mut negative = book("tool");
        negative.cuboid = Some([0.1, -1.0, 0.1]);
        let (meshes, warnings) = meshes_with_attachments(&robot, &[book("gripper"), two, negative]);
        assert_eq!(meshes.len(), base, "all three left out");
        assert!(warnings[0].contains("no link \"gripper\""), "{warnings:?}");
        assert!(warnings[1].contains("more than one shape"), "{warnings:?}");
        assert!(warnings[2].contains("finite, positive"), "{warnings:?}");
    }

    #[test]
    fn attachments_read_from_a_profile_pipeline() {
        let config: crate::pipeline::PipelineConfig = toml::from_str(
            "[[attach]]\nlink = \"tool\"\ncylinder = { radius = 0.03, length = 0.2 }\n",
        )
        .unwrap();
        assert_eq!(config.attach.len(), 1);
        assert!(config.attach[0].mesh().is_ok());
        assert!(
            toml::from_str::<crate::pipeline::PipelineConfig>(
                "[[attach]]\nlink = \"tool\"\ncone = 1.0\n"
            )
            .is_err()
        );
    }
}
