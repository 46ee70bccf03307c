//! Joint states by name -> the robot's joint vector.
//!
//! A [`JointMapper`] is built once per robot and session. Each call maps a message's
//! `(name, position)` pairs onto [`JointPositions`]:
//! - names the robot does not have are ignored and counted ([`JointMapper::unknown_total`]);
//! - moving, non-mimic joints the message lacks are set to zero, with one warning per
//!   mapper (session) naming them;
//! - mimic and fixed joints are derived, so their given values are ignored (not counted);
//! - a NaN or infinite position of a known joint is a [`RobotError::NonFiniteJoint`]
//!   error: the whole message is rejected, so NaN never reaches a pose.

use super::error::RobotError;
use super::kinematics::{JointPositions, Kinematics};
use std::collections::HashMap;

/// The result of mapping one joint-state message.
#[derive(Debug, Clone, PartialEq)]
pub struct MappedJoints {
    /// Positions in the robot's joint order.
    pub positions: JointPositions,
    /// Names in the message the robot does not have.
    pub unknown: usize,
    /// Moving, non-mimic joints missing from the message (set to zero).
    pub missing: Vec<String>,
}

/// Maps joint names to the robot's joint indices; see the module docs.
#[derive(Debug, Clone)]
pub struct JointMapper {
    index: HashMap<String, usize>,
    driven: Vec<bool>,
    names: Vec<String>,
    warned_missing: bool,
    unknown_total: u64,
}

impl JointMapper {
    /// A mapper for the joints of `kinematics`.
    pub fn new(kinematics: &Kinematics) -> Self {
        let joints = kinematics.joints();
        Self {
            index: joints
                .iter()
                .enumerate()
                .map(|(i, j)| (j.name.clone(), i))
                .collect(),
            driven: joints
                .iter()
                .map(|j| j.kind.is_moving() && j.mimic.is_none())
                .collect(),
            names: joints.iter().map(|j| j.name.clone()).collect(),
            warned_missing: false,
            unknown_total: 0,
        }
    }

    /// Maps parallel `names` and `positions` (as in `sensor_msgs/JointState`).
    pub fn map<S: AsRef<str>>(
        &mut self,
        names: &[S],
        positions: &[f64],
    ) -> Result<MappedJoints, RobotError> {
        if names.len() != positions.len() {
            return Err(RobotError::JointCount {
                expected: names.len(),
                got: positions.len(),
            });
        }
        self.map_pairs(
            names
                .iter()
                .map(AsRef::as_ref)
                .zip(positions.iter().copied()),
        )
    }

    /// Maps `(name, position)` pairs.
    pub fn map_pairs<'a>(
        &mut self,
        pairs: impl IntoIterator<Item = (&'a str, f64)>,
    ) -> Result<MappedJoints, RobotError> {
        let mut values = vec![0.0; self.names.len()];
        let mut given = vec![false; self.names.len()];
        let mut unknown = 0;
        for (name, value) in pairs {
            let Some(&j) = self.index.get(name) else {
                unknown += 1;
                continue;
            };
            if !self.driven[j] {
                continue;
            }
            if !value.is_finite() {
                return Err(RobotError::NonFiniteJoint {
                    joint: name.to_string(),
                    value,
                });
            }
            values[j] = value;
            given[j] = true;
        }
        self.unknown_total += unknown as u64;
        let missing: Vec<String> = (0..self.names.len())
            .filter(|&j| self.driven[j] && !given[j])
            .map(|j| self.names[j].clone())
            .collect();
        if !missing.is_empty() && !self.warned_missing {
            self.warned_missing = true;
            tracing::warn!(
                joints = ?missing,
                "joint states lack some joints; they are taken as 0 (warned once per session)"
            );
        }
        Ok(MappedJoints {
            positions: JointPositions(values),
            unknown,
            missing,
        })
    }

    /// Unknown names seen over the mapper's life.
    pub fn unknown_total(&self) -> u64 {
        self.unknown_total
    }

    /// Whether the missing-joints warning has been given.
    pub fn warned_missing(&self) -> bool {
        self.warned_missing
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kinematics::{Joint, JointKind, Mimic};
    use nalgebra::{Isometry3, Vector3};

    fn robot() -> Kinematics {
        let j = |name: &str, kind, child, mimic| Joint {
            name: name.into(),
            kind,
            parent: 0,
            child,
            parent_from_joint: Isometry3::identity(),
            axis: Vector3::z_axis(),
            limits: None,
            mimic,
        };
        Kinematics::new(
            (0..5).map(|i| format!("l{i}")).collect(),
            vec![
                j("a", JointKind::Revolute, 1, None),
                j("fixed", JointKind::Fixed, 2, None),
                j("b", JointKind::Prismatic, 3, None),
                j(
                    "m",
                    JointKind::Revolute,
                    4,
                    Some(Mimic {
                        joint: 0,
                        multiplier: 1.0,
                        offset: 0.0,
                    }),
                ),
            ],
        )
        .unwrap()
    }

    #[test]
    fn maps_by_name_counts_unknown_and_zeroes_missing() {
        let k = robot();
        let mut m = JointMapper::new(&k);
        let r = m
            .map(
                &["zzz", "b", "m", "fixed", "other"],
                &[1.0, 0.25, 7.0, 3.0, 2.0],
            )
            .unwrap();
        assert_eq!(r.positions.as_slice(), &[0.0, 0.0, 0.25, 0.0]);
        assert_eq!(r.unknown, 2);
        assert_eq!(r.missing, vec!["a".to_string()]);
        assert!(m.warned_missing());
        let r = m.map_pairs([("a", -1.5), ("b", 0.1), ("x", 0.0)]).unwrap();
        assert_eq!(r.positions.as_slice(), &[-1.5, 0.0, 0.1, 0.0]);
        assert!(r.missing.is_empty());
        assert_eq!(m.unknown_total(), 3);
    }

    #[test]
    fn non_finite_and_length_mismatch_are_errors() {
        let mut m = JointMapper::new(&robot());
        let e = m.map(&["a", "b"], &[0.0, f64::INFINITY]).unwrap_err();
        assert!(matches!(e, RobotError::NonFiniteJoint { ref joint, .. } if joint == "b"));
        let e = m.map(&["a", "b"], &[0.0]).unwrap_err();
        assert_eq!(
            e,
            RobotError::JointCount {
                expected: 2,
                got: 1
            }
        );
        // NaN for an unknown or derived joint is ignored, not an error.
        assert!(m.map(&["zzz", "m"], &[f64::NAN, f64::NAN]).is_ok());
    }
}
