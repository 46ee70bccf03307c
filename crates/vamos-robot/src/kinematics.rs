//! The joint tree and forward kinematics: `base_from_link` for every link, camera poses.
//!
//! Built once per robot ([`Kinematics::new`] validates the tree and precomputes each
//! joint's origin and the links in topological order); [`Kinematics::forward_into`] then
//! costs one isometry product per link.

use super::camera::CameraConvention;
use super::error::RobotError;
use nalgebra::{Isometry3, Translation3, Unit, UnitQuaternion, Vector3};
use serde::Serialize;

/// The kind of a URDF joint.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum JointKind {
    /// Rotation about the axis, limited.
    Revolute,
    /// Rotation about the axis, unlimited.
    Continuous,
    /// Translation along the axis, metres.
    Prismatic,
    /// No motion.
    Fixed,
    /// Six degrees of freedom in URDF; treated as fixed (its origin only).
    Floating,
    /// Planar motion in URDF; treated as fixed.
    Planar,
    /// Spherical (URDF 1.2); treated as fixed.
    Spherical,
}

impl JointKind {
    /// True for the kinds whose position moves the child (revolute, continuous, prismatic).
    pub fn is_moving(self) -> bool {
        matches!(self, Self::Revolute | Self::Continuous | Self::Prismatic)
    }
}

/// Position limits of a joint (radians or metres). Never enforced; see
/// [`Kinematics::out_of_limits`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct JointLimits {
    /// Lower limit.
    pub lower: f64,
    /// Upper limit.
    pub upper: f64,
}

/// A mimic relation: `position = multiplier * position(joint) + offset`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Mimic {
    /// Index of the mimicked joint (in the robot's joint list); never itself a mimic
    /// joint (chains are resolved when the robot is loaded).
    pub joint: usize,
    /// Multiplier (URDF default 1).
    pub multiplier: f64,
    /// Offset, radians or metres (URDF default 0).
    pub offset: f64,
}

/// One joint of the robot.
#[derive(Debug, Clone, PartialEq)]
pub struct Joint {
    /// The URDF name.
    pub name: String,
    /// Its kind.
    pub kind: JointKind,
    /// Parent link index.
    pub parent: usize,
    /// Child link index.
    pub child: usize,
    /// `parent_from_joint` at position zero (the URDF `<origin>`).
    pub parent_from_joint: Isometry3<f64>,
    /// Unit axis in the joint frame (x for fixed joints without a usable axis).
    pub axis: Unit<Vector3<f64>>,
    /// Position limits, when the URDF gives a non-empty range for a revolute or prismatic
    /// joint.
    pub limits: Option<JointLimits>,
    /// The mimic relation, if any.
    pub mimic: Option<Mimic>,
}

/// A joint outside its limits.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LimitViolation {
    /// Joint name.
    pub joint: String,
    /// Its (effective, after mimic) position.
    pub position: f64,
    /// Lower limit.
    pub lower: f64,
    /// Upper limit.
    pub upper: f64,
}

/// Joint positions in the robot's joint order (radians / metres), all finite. Entries of
/// fixed and mimic joints are ignored by forward kinematics (mimic positions come from the
/// mimicked joint). Build with [`Kinematics::positions`], [`Kinematics::zero_positions`]
/// or a [`super::joints::JointMapper`].
#[derive(Debug, Clone, PartialEq)]
pub struct JointPositions(pub(crate) Vec<f64>);

impl JointPositions {
    /// The values, one per joint.
    pub fn as_slice(&self) -> &[f64] {
        &self.0
    }
}

/// One step of the precomputed forward pass: `base_from[child] = base_from[parent] *
/// origin * motion(q)`.
#[derive(Debug, Clone)]
struct Step {
    parent: usize,
    child: usize,
    origin: Isometry3<f64>,
    kind: JointKind,
    axis: Unit<Vector3<f64>>,
    /// The joint whose position drives this one, with multiplier and offset.
    source: usize,
    multiplier: f64,
    offset: f64,
}

/// The validated joint tree of a robot.
#[derive(Debug, Clone)]
pub struct Kinematics {
    links: Vec<String>,
    joints: Vec<Joint>,
    root: usize,
    steps: Vec<Step>,
}

impl Kinematics {
    /// Validates the tree (unique names checked by the caller; one parent per link, one
    /// root, no cycles, mimic targets resolved) and precomputes the forward pass.
    pub fn new(links: Vec<String>, joints: Vec<Joint>) -> Result<Self, RobotError> {
        if links.is_empty() {
            return Err(RobotError::NoLinks);
        }
        let mut parent_joint: Vec<Option<usize>> = vec![None; links.len()];
        let mut children: Vec<Vec<usize>> = vec![Vec::new(); links.len()];
        for (j, joint) in joints.iter().enumerate() {
            if joint.parent >= links.len() || joint.child >= links.len() {
                return Err(RobotError::InvalidJoint {
                    joint: joint.name.clone(),
                    what: "link index",
                });
            }
            if let Some(first) = parent_joint[joint.child] {
                return Err(RobotError::TwoParents {
                    link: links[joint.child].clone(),
                    first: joints[first].name.clone(),
                    second: joint.name.clone(),
                });
            }
            parent_joint[joint.child] = Some(j);
            children[joint.parent].push(j);
        }
        let roots: Vec<usize> = (0..links.len())
            .filter(|&l| parent_joint[l].is_none())
            .collect();
        let root = match roots.as_slice() {
            [r] => *r,
            [] => {
                return Err(RobotError::KinematicCycle {
                    link: links[0].clone(),
                });
            }
            _ => {
                return Err(RobotError::MultipleRoots {
                    roots: roots.iter().map(|&l| links[l].clone()).collect(),
                });
            }
        };
        // Breadth-first from the root: parents before children.
        let mut order = Vec::with_capacity(joints.len());
        let mut queue = std::collections::VecDeque::from([root]);
        let mut seen = vec![false; links.len()];
        seen[root] = true;
        while let Some(l) = queue.pop_front() {
            for &j in &children[l] {
                let c = joints[j].child;
                if !seen[c] {
                    seen[c] = true;
                    order.push(j);
                    queue.push_back(c);
                }
            }
        }
        if let Some(l) = seen.iter().position(|s| !s) {
            // Every link has one parent and one link has none, so an unreached link sits on
            // a cycle detached from the root.
            return Err(RobotError::KinematicCycle {
                link: links[l].clone(),
            });
        }
        for joint in &joints {
            if let Some(m) = joint.mimic {
                let target = joints
                    .get(m.joint)
                    .ok_or_else(|| RobotError::InvalidJoint {
                        joint: joint.name.clone(),
                        what: "mimic",
                    })?;
                if target.mimic.is_some() {
                    return Err(RobotError::InvalidJoint {
                        joint: joint.name.clone(),
                        what: "mimic (chain not resolved)",
                    });
                }
            }
        }
        let steps = order
            .iter()
            .map(|&j| {
                let joint = &joints[j];
                let (source, multiplier, offset) = match joint.mimic {
                    Some(m) => (m.joint, m.multiplier, m.offset),
                    None => (j, 1.0, 0.0),
                };
                Step {
                    parent: joint.parent,
                    child: joint.child,
                    origin: joint.parent_from_joint,
                    kind: joint.kind,
                    axis: joint.axis,
                    source,
                    multiplier,
                    offset,
                }
            })
            .collect();
        Ok(Self {
            links,
            joints,
            root,
            steps,
        })
    }

    /// Link names; the index is the link index used everywhere (`LinkMesh::link`, poses).
    pub fn links(&self) -> &[String] {
        &self.links
    }

    /// The joints in URDF order (the order of [`JointPositions`]).
    pub fn joints(&self) -> &[Joint] {
        &self.joints
    }

    /// Index of the root link (the base frame).
    pub fn root(&self) -> usize {
        self.root
    }

    /// Index of a link by name.
    pub fn link_index(&self, name: &str) -> Option<usize> {
        self.links.iter().position(|l| l == name)
    }

    /// Index of a joint by name.
    pub fn joint_index(&self, name: &str) -> Option<usize> {
        self.joints.iter().position(|j| j.name == name)
    }

    /// All joints at zero.
    pub fn zero_positions(&self) -> JointPositions {
        JointPositions(vec![0.0; self.joints.len()])
    }

    /// Checked joint positions in joint order: one per joint, all finite.
    pub fn positions(&self, values: Vec<f64>) -> Result<JointPositions, RobotError> {
        if values.len() != self.joints.len() {
            return Err(RobotError::JointCount {
                expected: self.joints.len(),
                got: values.len(),
            });
        }
        if let Some((j, &v)) = values.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(RobotError::NonFiniteJoint {
                joint: self.joints[j].name.clone(),
                value: v,
            });
        }
        Ok(JointPositions(values))
    }

    /// The effective position of joint `j` (mimic joints follow their target; fixed joints
    /// are 0).
    pub fn effective_position(&self, q: &JointPositions, j: usize) -> f64 {
        let Some(joint) = self.joints.get(j) else {
            return 0.0;
        };
        if !joint.kind.is_moving() {
            return 0.0;
        }
        match joint.mimic {
            Some(m) => m.multiplier * q.0.get(m.joint).copied().unwrap_or(0.0) + m.offset,
            None => q.0.get(j).copied().unwrap_or(0.0),
        }
    }

    /// `base_from_link` for every link (index = link index; the root is the identity).
    pub fn forward(&self, q: &JointPositions) -> Result<Vec<Isometry3<f64>>, RobotError> {
        let mut out = Vec::new();
        self.forward_into(q, &mut out)?;
        Ok(out)
    }

    /// As [`Kinematics::forward`], into a reusable buffer (resized to the link count).
    pub fn forward_into(
        &self,
        q: &JointPositions,
        out: &mut Vec<Isometry3<f64>>,
    ) -> Result<(), RobotError> {
        if q.0.len() != self.joints.len() {
            return Err(RobotError::JointCount {
                expected: self.joints.len(),
                got: q.0.len(),
            });
        }
        out.clear();
        out.resize(self.links.len(), Isometry3::identity());
        for s in &self.steps {
            let base_from_joint = out[s.parent] * s.origin;
            let value = s.multiplier * q.0[s.source] + s.offset;
            out[s.child] = match s.kind {
                JointKind::Revolute | JointKind::Continuous => {
                    base_from_joint
                        * Isometry3::from_parts(
                            Translation3::identity(),
                            UnitQuaternion::from_axis_angle(&s.axis, value),
                        )
                }
                JointKind::Prismatic => {
                    base_from_joint * Translation3::from(s.axis.into_inner() * value)
                }
                JointKind::Fixed
                | JointKind::Floating
                | JointKind::Planar
                | JointKind::Spherical => base_from_joint,
            };
        }
        Ok(())
    }

    /// Joints (revolute and prismatic with limits) outside their limits at `q`. Mimic
    /// joints are not listed: their positions follow their leaders and cannot be set, so
    /// a violation is reported on the leader (when it is outside its own limits) only.
    pub fn out_of_limits(&self, q: &JointPositions) -> Vec<LimitViolation> {
        self.joints
            .iter()
            .enumerate()
            .filter(|(_, joint)| joint.mimic.is_none())
            .filter_map(|(j, joint)| {
                let lim = joint.limits?;
                let position = self.effective_position(q, j);
                (position < lim.lower || position > lim.upper).then(|| LimitViolation {
                    joint: joint.name.clone(),
                    position,
                    lower: lim.lower,
                    upper: lim.upper,
                })
            })
            .collect()
    }

    /// Resolves a camera link by name for [`CameraMount::camera_from_base`].
    pub fn camera(
        &self,
        frame: &str,
        convention: CameraConvention,
    ) -> Result<CameraMount, RobotError> {
        let link = self
            .link_index(frame)
            .ok_or_else(|| RobotError::UnknownCameraLink {
                name: frame.to_string(),
            })?;
        Ok(CameraMount {
            link,
            link_from_optical: convention.frame_from_optical(),
        })
    }
}

/// A camera attached to a link, resolved once.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraMount {
    /// The link index.
    pub link: usize,
    /// `link_from_optical` (from the [`CameraConvention`]).
    pub link_from_optical: Isometry3<f64>,
}

impl CameraMount {
    /// `camera_from_base` (optical camera frame: z forward, x right, y down) from the
    /// `base_from_link` poses of [`Kinematics::forward`]; `None` when `poses` does not hold
    /// the link.
    pub fn camera_from_base(&self, base_from_link: &[Isometry3<f64>]) -> Option<Isometry3<f64>> {
        let base_from_camera = base_from_link.get(self.link)? * self.link_from_optical;
        Some(base_from_camera.inverse())
    }
}

/// Rotation from URDF roll-pitch-yaw (fixed axes x, y, z: `R = Rz(yaw) Ry(pitch) Rx(roll)`)
/// and a translation.
pub fn isometry_from_xyz_rpy(xyz: [f64; 3], rpy: [f64; 3]) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(xyz[0], xyz[1], xyz[2]),
        UnitQuaternion::from_euler_angles(rpy[0], rpy[1], rpy[2]),
    )
}

#[cfg(test)]
#[path = "kinematics_tests.rs"]
mod tests;
