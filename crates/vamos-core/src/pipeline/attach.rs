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
//! # Optional: there only while a joint reads below (or above) a value, e.g. a grasped
//! # object while the gripper is closed on it.
//! while = { joint = "finger_left_joint", below = 0.03 }
//! ```
//!
//! Every shape is drawn as a link of its own, numbered after the robot's links, so a shape
//! that is absent this frame is moved behind the camera instead of re-preparing the
//! renderer.

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
    /// When the shape is there (always when not given).
    #[serde(default, rename = "while", skip_serializing_if = "Option::is_none")]
    pub present_while: Option<JointCondition>,
}

/// A condition on one joint's reported position (radians or metres): the shape is there
/// while the position is below `below` and above `above` (either or both).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct JointCondition {
    /// The joint (a URDF joint name).
    pub joint: String,
    /// There while the joint reads below this.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub below: Option<f64>,
    /// There while the joint reads above this.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub above: Option<f64>,
}

impl JointCondition {
    /// Whether `position` meets the condition (a position that is not finite does not).
    fn holds(&self, position: f64) -> bool {
        position.is_finite()
            && self.below.is_none_or(|b| position < b)
            && self.above.is_none_or(|a| position > a)
    }

    /// Why the condition cannot be used, if it cannot.
    fn problem(&self) -> Option<String> {
        if self.below.is_none() && self.above.is_none() {
            return Some("`while` needs `below`, `above` or both".into());
        }
        if self.below.iter().chain(&self.above).any(|v| !v.is_finite()) {
            return Some("`while` bounds must be finite".into());
        }
        if let (Some(b), Some(a)) = (self.below, self.above)
            && a >= b
        {
            return Some(format!("`while` is never true (above {a} and below {b})"));
        }
        None
    }
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

/// One usable attached shape: its robot link and, when gated, the joint index and the
/// condition.
#[derive(Debug, Clone)]
struct Shape {
    link: usize,
    gate: Option<(usize, JointCondition)>,
}

/// The attached shapes of one robot, ready to render (see the module docs): the robot's
/// meshes plus one pseudo-link per shape, and which shapes are there this frame.
#[derive(Debug, Clone, Default)]
pub struct AttachedShapes {
    shapes: Vec<Shape>,
    present: Vec<bool>,
}

/// How far behind the camera an absent shape is put, metres (far beyond any near plane
/// and any shape's size, [`MAX_SHAPE_M`]).
const HIDDEN_BEHIND_M: f64 = 1.0e3;

impl AttachedShapes {
    /// The robot's meshes with the usable shapes added (shape `k` on link
    /// `robot links + k`), the shapes, and a warning for each shape left out: on a link or
    /// gated by a joint the robot does not have, with a bad size or a condition that cannot
    /// hold. The warnings are also logged; the profile keeps working with the body it has.
    pub fn new(robot: &Robot, attachments: &[Attachment]) -> (Vec<LinkMesh>, Self, Vec<String>) {
        let kinematics = robot.kinematics();
        let first = kinematics.links().len();
        let mut meshes = robot.link_meshes().to_vec();
        let mut shapes = Vec::new();
        let mut warnings = Vec::new();
        for (i, a) in attachments.iter().enumerate() {
            let Some(link) = kinematics.link_index(&a.link) else {
                warnings.push(format!(
                    "attach[{i}]: the robot has no link {:?}; shape left out",
                    a.link
                ));
                continue;
            };
            let gate = match &a.present_while {
                None => None,
                Some(c) => {
                    if let Some(problem) = c.problem() {
                        warnings.push(format!(
                            "attach[{i}] on {:?}: {problem}; shape left out",
                            a.link
                        ));
                        continue;
                    }
                    let Some(joint) = kinematics.joint_index(&c.joint) else {
                        warnings.push(format!(
                            "attach[{i}] on {:?}: `while` names joint {:?}, which the robot does not have; shape left out",
                            a.link, c.joint
                        ));
                        continue;
                    };
                    Some((joint, c.clone()))
                }
            };
            match a.mesh() {
                Ok(mesh) => {
                    meshes.push(LinkMesh {
                        link: first + shapes.len(),
                        mesh,
                    });
                    shapes.push(Shape { link, gate });
                }
                Err(e) => {
                    warnings.push(format!("attach[{i}] on {:?}: {e}; shape left out", a.link))
                }
            }
        }
        for w in &warnings {
            tracing::warn!("{w}");
        }
        let present = vec![false; shapes.len()];
        (meshes, Self { shapes, present }, warnings)
    }

    /// Whether there are shapes to draw.
    pub fn is_empty(&self) -> bool {
        self.shapes.is_empty()
    }

    /// Decides which shapes are there from the joint positions `q` (the robot's joint
    /// order): ungated ones always, gated ones while their condition holds.
    pub fn update(&mut self, q: &[f64]) {
        for (present, shape) in self.present.iter_mut().zip(&self.shapes) {
            *present = match &shape.gate {
                None => true,
                Some((joint, c)) => q.get(*joint).is_some_and(|&v| c.holds(v)),
            };
        }
    }

    /// Which shapes are there (in the order of [`AttachedShapes::new`]'s usable shapes).
    pub fn present(&self) -> &[bool] {
        &self.present
    }

    /// `out` = the robot's link poses `links` followed by each shape's pose: its link's
    /// while it is there, else behind the camera `camera_from_base`. The same decision
    /// serves a frame's two views, so a shape's flow is its link's motion.
    pub fn poses(
        &self,
        links: &[Isometry3<f64>],
        camera_from_base: &Isometry3<f64>,
        out: &mut Vec<Isometry3<f64>>,
    ) {
        out.clear();
        out.extend_from_slice(links);
        let hidden =
            camera_from_base.inverse() * Isometry3::translation(0.0, 0.0, -HIDDEN_BEHIND_M);
        out.extend(self.shapes.iter().zip(&self.present).map(
            |(s, &present)| match links.get(s.link) {
                Some(pose) if present => *pose,
                _ => hidden,
            },
        ));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use vamos_robot::RobotConfig;

    const URDF: &str = r#"<robot name="r">
      <link name="base"><visual><geometry><box size="0.1 0.1 0.1"/></geometry></visual></link>
      <link name="tool"/>
      <link name="finger"/>
      <joint name="j" type="revolute"><parent link="base"/><child link="tool"/>
        <axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
      <joint name="grip" type="prismatic"><parent link="tool"/><child link="finger"/>
        <axis xyz="0 1 0"/><limit lower="0" upper="0.05" effort="1" velocity="1"/></joint>
    </robot>"#;

    fn robot() -> Robot {
        Robot::from_urdf_str(URDF, None, &RobotConfig::default()).unwrap()
    }

    fn book(link: &str) -> Attachment {
        Attachment {
            link: link.into(),
            cuboid: Some([0.17, 0.045, 0.24]),
            cylinder: None,
            sphere: None,
            xyz: [0.0, 0.0, 0.09],
            rpy: [0.0, 0.0, 0.0],
            present_while: None,
        }
    }

    fn held(below: Option<f64>, above: Option<f64>, joint: &str) -> Attachment {
        Attachment {
            present_while: Some(JointCondition {
                joint: joint.into(),
                below,
                above,
            }),
            ..book("tool")
        }
    }

    #[test]
    fn a_shape_is_a_link_of_its_own_and_bad_ones_are_left_out_with_a_reason() {
        let robot = robot();
        let base = robot.link_meshes().len();
        let links = robot.kinematics().links().len();
        let (meshes, shapes, warnings) = AttachedShapes::new(&robot, &[book("tool")]);
        assert!(warnings.is_empty(), "{warnings:?}");
        assert_eq!(meshes.len(), base + 1);
        let added = meshes.last().unwrap();
        assert_eq!(
            added.link, links,
            "the first pseudo-link follows the robot's links"
        );
        assert_eq!(
            shapes.shapes[0].link,
            robot.kinematics().link_index("tool").unwrap()
        );
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
        let bad = [
            book("gripper"),
            two,
            negative,
            held(Some(0.03), None, "wrist"),
            held(None, None, "grip"),
            held(Some(0.01), Some(0.02), "grip"),
            held(Some(f64::NAN), None, "grip"),
        ];
        let (meshes, shapes, warnings) = AttachedShapes::new(&robot, &bad);
        assert_eq!(meshes.len(), base, "all left out");
        assert!(shapes.is_empty());
        let expected = [
            "no link \"gripper\"",
            "more than one shape",
            "finite, positive",
            "joint \"wrist\", which the robot does not have",
            "needs `below`, `above` or both",
            "never true",
            "bounds must be finite",
        ];
        assert_eq!(warnings.len(), expected.len(), "{warnings:?}");
        for (w, e) in warnings.iter().zip(expected) {
            assert!(w.contains(e), "{w:?} should say {e:?}");
        }
    }

    #[test]
    fn a_gated_shape_follows_its_link_only_while_the_joint_condition_holds() {
        let robot = robot();
        let links = robot.kinematics().links().len();
        let grip = robot.kinematics().joint_index("grip").unwrap();
        let (_, mut shapes, warnings) = AttachedShapes::new(
            &robot,
            &[
                book("tool"),
                held(Some(0.03), None, "grip"),
                held(None, Some(0.01), "grip"),
            ],
        );
        assert!(warnings.is_empty(), "{warnings:?}");
        let camera_from_base = Isometry3::translation(0.1, -0.2, 1.5);
        let mut q = vec![0.3; robot.kinematics().joints().len()];
        let poses = robot.forward(&robot.kinematics().zero_positions()).unwrap();
        let tool = robot.kinematics().link_index("tool").unwrap();
        let mut out = Vec::new();
        for (opening, present) in [
            (0.02, [true, true, true]),
            (0.04, [true, false, true]),
            (0.005, [true, true, false]),
            (f64::NAN, [true, false, false]),
        ] {
            q[grip] = opening;
            shapes.update(&q);
            assert_eq!(shapes.present(), present, "opening {opening}");
            shapes.poses(&poses, &camera_from_base, &mut out);
            assert_eq!(out.len(), links + 3);
            assert_eq!(&out[..links], poses.as_slice());
            for (k, &there) in present.iter().enumerate() {
                let pose = out[links + k];
                if there {
                    assert_eq!(pose, poses[tool]);
                } else {
                    // Far behind the camera: nothing of it can be drawn.
                    let z = (camera_from_base * pose).translation.z;
                    assert!(z < -900.0, "{z}");
                }
            }
        }
    }

    #[test]
    fn attachments_read_from_a_profile_pipeline() {
        let config: crate::pipeline::PipelineConfig = toml::from_str(
            "[[attach]]\nlink = \"tool\"\ncylinder = { radius = 0.03, length = 0.2 }\n\
             while = { joint = \"grip\", below = 0.03 }\n",
        )
        .unwrap();
        assert_eq!(config.attach.len(), 1);
        assert!(config.attach[0].mesh().is_ok());
        assert_eq!(
            config.attach[0].present_while,
            Some(JointCondition {
                joint: "grip".into(),
                below: Some(0.03),
                above: None
            })
        );
        for bad in [
            "[[attach]]\nlink = \"tool\"\ncone = 1.0\n",
            "[[attach]]\nlink = \"tool\"\nsphere = 0.1\nwhile = { joint = \"grip\", under = 0.03 }\n",
        ] {
            assert!(
                toml::from_str::<crate::pipeline::PipelineConfig>(bad).is_err(),
                "{bad}"
            );
        }
    }
}
