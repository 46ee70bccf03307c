//! The robot's state for the kinematic novelty detector `e_k`
//! ([`crate::eval::novelty`]), from the joint states at the image's stamp: where the
//! robot is and where it is heading.
//!
//! - `state = "joints"` (the default): each joint's position, then its velocity times
//!   `velocity_s` (the distance it covers in that time). At calibration every joint is
//!   scaled by its nominal range (the 1st to 99th percentile of its positions over the
//!   training frames, at least `min_range`), its velocity by the same: one unit is a
//!   joint's whole nominal travel whatever the joint, so a wrist that hardly moves in a
//!   nominal run counts when it turns, and radians and metres mix.
//! - `state = "links"`: each link as three points in the robot's base frame (its origin
//!   and the points `lever_m` along its x and y axes, so a rotation counts as the
//!   displacement of a point that far out), then their velocities times `velocity_s`; in
//!   metres, unscaled: a physical distance, whatever the joints.

use crate::eval::nominal::quantile_sorted;
use nalgebra::{Isometry3, Vector3};
use serde::{Deserialize, Serialize};

/// What a state is made of.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum StateKind {
    /// Joint positions and velocities, scaled by their nominal ranges.
    #[default]
    Joints,
    /// Three points per link and their velocities, metres.
    Links,
}

/// The `[pipeline.kinematics]` settings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct KinematicsParams {
    /// What a state is made of.
    pub state: StateKind,
    /// `state = "joints"`: the smallest nominal range a joint is scaled by (radians or
    /// metres), for joints that hardly move in the nominal runs.
    pub min_range: f64,
    /// `state = "links"`: a link's orientation enters the state as the positions of two
    /// points this far (metres) along its x and y axes.
    pub lever_m: f64,
    /// Velocities enter the state as the distance covered in this many seconds; 0: the
    /// state is positions only (a robot stopped where a nominal run passes through is
    /// then not novel).
    pub velocity_s: f64,
}

impl Default for KinematicsParams {
    fn default() -> Self {
        Self {
            state: StateKind::Joints,
            min_range: 0.01,
            lever_m: 0.1,
            velocity_s: 0.5,
        }
    }
}

/// Largest `velocity_s`, seconds.
pub const MAX_VELOCITY_S: f64 = 10.0;
/// Largest `lever_m`, metres.
pub const MAX_LEVER_M: f64 = 10.0;
/// The quantiles whose distance is a joint's nominal range.
const RANGE_QUANTILES: (f64, f64) = (0.01, 0.99);

impl KinematicsParams {
    /// Refuses values no state can be made with.
    pub fn validate(&self) -> Result<(), String> {
        if !(self.velocity_s.is_finite() && (0.0..=MAX_VELOCITY_S).contains(&self.velocity_s)) {
            return Err(format!(
                "kinematics.velocity_s = {} must lie in [0, {MAX_VELOCITY_S}] seconds",
                self.velocity_s
            ));
        }
        if !(self.lever_m.is_finite() && (0.0..=MAX_LEVER_M).contains(&self.lever_m)) {
            return Err(format!(
                "kinematics.lever_m = {} must lie in [0, {MAX_LEVER_M}] metres",
                self.lever_m
            ));
        }
        if !(self.min_range.is_finite() && self.min_range > 0.0) {
            return Err(format!(
                "kinematics.min_range = {} must be a finite number > 0",
                self.min_range
            ));
        }
        Ok(())
    }

    /// The positions part of a state: the joints' positions `q` (joint order), or each of
    /// the links' three points (x, y, z each) from `base_from_link`.
    pub fn positions(&self, q: &[f64], base_from_link: &[Isometry3<f64>]) -> Vec<f64> {
        match self.state {
            StateKind::Joints => q.to_vec(),
            StateKind::Links => {
                let mut out = Vec::with_capacity(9 * base_from_link.len());
                for link in base_from_link {
                    let o = link.translation.vector;
                    let r = link.rotation;
                    for p in [
                        o,
                        o + r * Vector3::x() * self.lever_m,
                        o + r * Vector3::y() * self.lever_m,
                    ] {
                        out.extend([p.x, p.y, p.z]);
                    }
                }
                out
            }
        }
    }

    /// The state of a frame with [`Self::positions`] `now`, the previous processed
    /// frame's `previous` (`dt_s` seconds earlier): the positions, then, with a
    /// `velocity_s` above 0, their change per second times `velocity_s`. `None` when
    /// velocities are wanted and there is no previous frame (or `dt_s` is not positive)
    /// or the lengths differ.
    pub fn state(&self, now: &[f64], previous: Option<(&[f64], f64)>) -> Option<Vec<f32>> {
        let mut state: Vec<f32> = now.iter().map(|&v| v as f32).collect();
        if self.velocity_s > 0.0 {
            let (before, dt_s) = previous?;
            if before.len() != now.len() || dt_s.is_nan() || dt_s <= 0.0 {
                return None;
            }
            let k = self.velocity_s / dt_s;
            state.extend(now.iter().zip(before).map(|(a, b)| ((a - b) * k) as f32));
        }
        Some(state)
    }

    /// The scale of each value of states of `dims` values (`state = "joints"`): each
    /// joint's nominal range over `states`, at least `min_range`, for its position and its
    /// velocity alike. `None` for `state = "links"` (metres, unscaled) or without a state
    /// of that length.
    pub fn scale(&self, states: &[&[f32]], dims: usize) -> Option<Vec<f64>> {
        if self.state == StateKind::Links {
            return None;
        }
        let joints = if self.velocity_s > 0.0 {
            dims / 2
        } else {
            dims
        };
        let rows: Vec<&[f32]> = states.iter().copied().filter(|s| s.len() == dims).collect();
        if rows.is_empty() || joints == 0 {
            return None;
        }
        let ranges: Vec<f64> = (0..joints)
            .map(|j| {
                let mut v: Vec<f64> = rows
                    .iter()
                    .map(|s| f64::from(s[j]))
                    .filter(|x| x.is_finite())
                    .collect();
                if v.is_empty() {
                    return self.min_range;
                }
                v.sort_by(f64::total_cmp);
                let range =
                    quantile_sorted(&v, RANGE_QUANTILES.1) - quantile_sorted(&v, RANGE_QUANTILES.0);
                range.max(self.min_range)
            })
            .collect();
        Some(ranges.iter().cycle().take(dims).copied().collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    fn close(got: &[f32], want: &[f64]) {
        assert_eq!(got.len(), want.len(), "{got:?}");
        for (a, b) in got.iter().zip(want) {
            assert!((f64::from(*a) - b).abs() < 1e-6, "{got:?} vs {want:?}");
        }
    }

    #[test]
    fn a_state_is_positions_then_their_change_over_velocity_s() {
        let p = KinematicsParams {
            velocity_s: 0.5,
            ..KinematicsParams::default()
        };
        let now = p.positions(&[0.0, 0.3], &[]);
        assert_eq!(
            p.state(&now, None),
            None,
            "velocities need a previous frame"
        );
        // Joint 1 moved 0.2 in 0.1 s: 2 per second, 1 in 0.5 s.
        let s = p.state(&now, Some((&[0.0, 0.1], 0.1))).unwrap();
        close(&s, &[0.0, 0.3, 0.0, 1.0]);
        let positions = KinematicsParams {
            velocity_s: 0.0,
            ..p
        };
        close(&positions.state(&now, None).unwrap(), &[0.0, 0.3]);
        assert_eq!(p.state(&now, Some((&[0.0], 0.1))), None);
        assert_eq!(p.state(&now, Some((&[0.0, 0.1], 0.0))), None);
    }

    #[test]
    fn links_are_three_points_and_a_rotation_about_the_origin_moves_two() {
        let p = KinematicsParams {
            state: StateKind::Links,
            lever_m: 0.1,
            ..KinematicsParams::default()
        };
        let turned = Isometry3::from_parts(
            Translation3::new(0.0, 0.0, 1.0),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), std::f64::consts::FRAC_PI_2),
        );
        let got = p.positions(&[], &[turned]);
        // x now points along y, y along -x.
        let want = [0.0, 0.0, 1.0, 0.0, 0.1, 1.0, -0.1, 0.0, 1.0];
        assert_eq!(got.len(), want.len());
        for (a, b) in got.iter().zip(want) {
            assert!((a - b).abs() < 1e-12, "{got:?}");
        }
        assert_eq!(
            p.scale(&[&[0.0; 18]], 18),
            None,
            "links are metres, unscaled"
        );
    }

    #[test]
    fn joints_are_scaled_by_their_nominal_range_velocities_alike() {
        let p = KinematicsParams::default();
        // Joint 0 travels 0..2, joint 1 never moves: its range is min_range.
        let states: Vec<Vec<f32>> = (0..=100)
            .map(|i| vec![i as f32 * 0.02, 0.5, 0.1, 0.0])
            .collect();
        let rows: Vec<&[f32]> = states.iter().map(Vec::as_slice).collect();
        let scale = p.scale(&rows, 4).unwrap();
        assert_eq!(scale.len(), 4);
        assert!((scale[0] - 1.96).abs() < 1e-6, "{scale:?}");
        assert_eq!(scale[1], p.min_range);
        assert_eq!((scale[2], scale[3]), (scale[0], scale[1]));
        assert_eq!(p.scale(&rows, 6), None, "no state of that length");
    }

    #[test]
    fn out_of_range_parameters_are_refused() {
        let ok = KinematicsParams::default();
        assert!(ok.validate().is_ok());
        for bad in [
            KinematicsParams {
                velocity_s: -1.0,
                ..ok
            },
            KinematicsParams {
                velocity_s: f64::NAN,
                ..ok
            },
            KinematicsParams {
                lever_m: f64::INFINITY,
                ..ok
            },
            KinematicsParams {
                min_range: 0.0,
                ..ok
            },
        ] {
            assert!(bad.validate().is_err(), "{bad:?}");
        }
    }
}
