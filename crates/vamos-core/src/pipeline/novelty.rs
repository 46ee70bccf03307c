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
//!   With `effort = true`, each joint's effort (torque or force) from the joint states
//!   follows, smoothed by a causal median of the last `effort_window` processed frames
//!   ([`EffortWindow`]) and scaled by its whole nominal range (smallest to largest over the
//!   training frames, at least [`MIN_EFFORT_RANGE_SHARE`] of the widest joint's): a
//!   collision or a jam loads the joints where the positions still look nominal. The
//!   whole range, not the 1st to 99th percentile, because efforts have short nominal peaks
//!   (a grasp, a start from rest) that a clipped range would call novel.
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
    /// `state = "joints"`: the joints' efforts (torques or forces) of the joint states
    /// enter the state too. A frame whose joint states carry no efforts then has no `e_k`.
    pub effort: bool,
    /// `effort = true`: efforts are the median of the last this many processed frames'
    /// (1, the default: as read), for robots whose effort readings are noisy enough that
    /// one sample should not count as a load. Measured on two simulated robots, smoothing
    /// over 3 frames lost more than it gained (docs/detection-history.md, "Joint efforts
    /// in `e_k`").
    pub effort_window: usize,
}

impl Default for KinematicsParams {
    fn default() -> Self {
        Self {
            state: StateKind::Joints,
            min_range: 0.01,
            lever_m: 0.1,
            velocity_s: 0.5,
            effort: false,
            effort_window: 1,
        }
    }
}

/// Largest `velocity_s`, seconds.
pub const MAX_VELOCITY_S: f64 = 10.0;
/// Largest `lever_m`, metres.
pub const MAX_LEVER_M: f64 = 10.0;
/// Largest `effort_window`, frames.
pub const MAX_EFFORT_WINDOW: usize = 31;
/// The quantiles whose distance is a joint's nominal range.
const RANGE_QUANTILES: (f64, f64) = (0.01, 0.99);
/// A joint's effort range is at least this share of the widest joint's (a joint whose
/// effort never changes in the nominal runs would otherwise make any change infinitely
/// novel).
pub const MIN_EFFORT_RANGE_SHARE: f64 = 0.01;

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
        if !(1..=MAX_EFFORT_WINDOW).contains(&self.effort_window) {
            return Err(format!(
                "kinematics.effort_window = {} must lie in [1, {MAX_EFFORT_WINDOW}] frames",
                self.effort_window
            ));
        }
        if self.effort && self.state != StateKind::Joints {
            return Err("kinematics.effort = true needs state = \"joints\"".into());
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
    /// frame's `previous` (`dt_s` seconds earlier) and the (smoothed) joint efforts
    /// `efforts`: the positions, then, with a `velocity_s` above 0, their change per second
    /// times `velocity_s`, then, with `effort`, the efforts. `None` when velocities are
    /// wanted and there is no previous frame (or `dt_s` is not positive), when efforts are
    /// wanted and there are none (or not one per position, or one is not finite), or when
    /// the lengths differ.
    pub fn state(
        &self,
        now: &[f64],
        previous: Option<(&[f64], f64)>,
        efforts: Option<&[f64]>,
    ) -> Option<Vec<f32>> {
        let mut state: Vec<f32> = now.iter().map(|&v| v as f32).collect();
        if self.velocity_s > 0.0 {
            let (before, dt_s) = previous?;
            if before.len() != now.len() || dt_s.is_nan() || dt_s <= 0.0 {
                return None;
            }
            let k = self.velocity_s / dt_s;
            state.extend(now.iter().zip(before).map(|(a, b)| ((a - b) * k) as f32));
        }
        if self.effort {
            let efforts = efforts?;
            if efforts.len() != now.len() || !efforts.iter().all(|e| e.is_finite()) {
                return None;
            }
            state.extend(efforts.iter().map(|&e| e as f32));
        }
        Some(state)
    }

    /// The scale of each value of states of `dims` values (`state = "joints"`): each
    /// joint's nominal range over `states`, at least `min_range`, for its position and its
    /// velocity alike; each effort's whole nominal range (see the module docs). `None` for
    /// `state = "links"` (metres, unscaled) or without a state of that length.
    pub fn scale(&self, states: &[&[f32]], dims: usize) -> Option<Vec<f64>> {
        if self.state == StateKind::Links {
            return None;
        }
        let parts = 1 + usize::from(self.velocity_s > 0.0) + usize::from(self.effort);
        let joints = dims / parts;
        let rows: Vec<&[f32]> = states.iter().copied().filter(|s| s.len() == dims).collect();
        if rows.is_empty() || joints == 0 || !dims.is_multiple_of(parts) {
            return None;
        }
        let column = |j: usize| -> Vec<f64> {
            let mut v: Vec<f64> = rows
                .iter()
                .map(|s| f64::from(s[j]))
                .filter(|x| x.is_finite())
                .collect();
            v.sort_by(f64::total_cmp);
            v
        };
        let ranges: Vec<f64> = (0..joints)
            .map(|j| {
                let v = column(j);
                if v.is_empty() {
                    return self.min_range;
                }
                let range =
                    quantile_sorted(&v, RANGE_QUANTILES.1) - quantile_sorted(&v, RANGE_QUANTILES.0);
                range.max(self.min_range)
            })
            .collect();
        let mut scale: Vec<f64> = ranges
            .iter()
            .cycle()
            .take(joints * (1 + usize::from(self.velocity_s > 0.0)))
            .copied()
            .collect();
        if self.effort {
            let first = dims - joints;
            let spans: Vec<f64> = (first..dims)
                .map(|j| {
                    let v = column(j);
                    match (v.first(), v.last()) {
                        (Some(lo), Some(hi)) => hi - lo,
                        _ => 0.0,
                    }
                })
                .collect();
            let widest = spans.iter().copied().fold(0.0, f64::max);
            // Efforts that never change at all: one unit of whatever they are measured in.
            let floor = if widest > 0.0 {
                widest * MIN_EFFORT_RANGE_SHARE
            } else {
                1.0
            };
            scale.extend(spans.iter().map(|s| s.max(floor)));
        }
        Some(scale)
    }
}

/// The causal median of the last few joint-effort vectors (`effort_window` of
/// [`KinematicsParams`]); a frame without efforts starts the window afresh.
#[derive(Debug, Clone, Default)]
pub struct EffortWindow {
    recent: std::collections::VecDeque<Vec<f64>>,
}

impl EffortWindow {
    /// Takes this frame's efforts (`None`: none read) and answers the per-joint median of
    /// the last `window` frames' (fewer at the start), or `None` without efforts.
    pub fn push(&mut self, efforts: Option<Vec<f64>>, window: usize) -> Option<Vec<f64>> {
        let Some(efforts) = efforts else {
            self.recent.clear();
            return None;
        };
        if self.recent.back().is_some_and(|r| r.len() != efforts.len()) {
            self.recent.clear();
        }
        self.recent.push_back(efforts);
        while self.recent.len() > window.max(1) {
            self.recent.pop_front();
        }
        let n = self.recent.back().map_or(0, Vec::len);
        let mut column = Vec::with_capacity(self.recent.len());
        Some(
            (0..n)
                .map(|j| {
                    column.clear();
                    column.extend(self.recent.iter().map(|r| r[j]));
                    column.sort_by(f64::total_cmp);
                    let m = column.len();
                    if m % 2 == 1 {
                        column[m / 2]
                    } else {
                        0.5 * (column[m / 2 - 1] + column[m / 2])
                    }
                })
                .collect(),
        )
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
            p.state(&now, None, None),
            None,
            "velocities need a previous frame"
        );
        // Joint 1 moved 0.2 in 0.1 s: 2 per second, 1 in 0.5 s.
        let s = p.state(&now, Some((&[0.0, 0.1], 0.1)), None).unwrap();
        close(&s, &[0.0, 0.3, 0.0, 1.0]);
        let positions = KinematicsParams {
            velocity_s: 0.0,
            ..p
        };
        close(&positions.state(&now, None, None).unwrap(), &[0.0, 0.3]);
        assert_eq!(p.state(&now, Some((&[0.0], 0.1)), None), None);
        assert_eq!(p.state(&now, Some((&[0.0, 0.1], 0.0)), None), None);
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
            KinematicsParams {
                effort_window: 0,
                ..ok
            },
            KinematicsParams {
                effort: true,
                state: StateKind::Links,
                ..ok
            },
        ] {
            assert!(bad.validate().is_err(), "{bad:?}");
        }
    }

    #[test]
    fn efforts_follow_the_velocities_and_are_scaled_by_their_whole_range() {
        let p = KinematicsParams {
            effort: true,
            ..KinematicsParams::default()
        };
        let now = [0.0, 0.3];
        let s = p
            .state(&now, Some((&[0.0, 0.1], 0.1)), Some(&[5.0, -1.0]))
            .unwrap();
        close(&s, &[0.0, 0.3, 0.0, 1.0, 5.0, -1.0]);
        assert_eq!(p.state(&now, Some((&now, 0.1)), None), None, "no efforts");
        assert_eq!(p.state(&now, Some((&now, 0.1)), Some(&[1.0])), None);
        assert_eq!(
            p.state(&now, Some((&now, 0.1)), Some(&[1.0, f64::NAN])),
            None
        );
        // Joint 0's effort spans -10..30 with one peak (the whole span counts), joint 1's
        // never changes (1 % of the widest).
        let states: Vec<Vec<f32>> = (0..=100)
            .map(|i| {
                let e = if i == 50 {
                    30.0
                } else {
                    -10.0 + i as f32 * 0.1
                };
                vec![i as f32 * 0.02, 0.5, 0.1, 0.0, e, 2.0]
            })
            .collect();
        let rows: Vec<&[f32]> = states.iter().map(Vec::as_slice).collect();
        let scale = p.scale(&rows, 6).unwrap();
        assert!((scale[0] - 1.96).abs() < 1e-6, "{scale:?}");
        assert_eq!((scale[2], scale[3]), (scale[0], scale[1]));
        assert!((scale[4] - 40.0).abs() < 1e-4, "{scale:?}");
        assert!((scale[5] - 0.4).abs() < 1e-6, "{scale:?}");
        assert_eq!(p.scale(&rows, 4), None, "not a state of this layout");
        let still: Vec<&[f32]> = vec![&[0.0, 0.0, 0.0, 0.0, 0.0, 0.0]];
        assert_eq!(p.scale(&still, 6).unwrap()[4..], [1.0, 1.0]);
    }

    #[test]
    fn the_effort_window_is_a_causal_median_restarted_by_a_gap() {
        let mut w = EffortWindow::default();
        assert_eq!(w.push(Some(vec![1.0, 0.0]), 3), Some(vec![1.0, 0.0]));
        assert_eq!(w.push(Some(vec![100.0, 2.0]), 3), Some(vec![50.5, 1.0]));
        // One spike among three is gone.
        assert_eq!(w.push(Some(vec![2.0, 4.0]), 3), Some(vec![2.0, 2.0]));
        assert_eq!(w.push(Some(vec![3.0, 6.0]), 3), Some(vec![3.0, 4.0]));
        assert_eq!(w.push(None, 3), None);
        assert_eq!(w.push(Some(vec![7.0, 7.0]), 3), Some(vec![7.0, 7.0]));
        assert_eq!(
            w.push(Some(vec![9.0]), 1),
            Some(vec![9.0]),
            "another length"
        );
    }
}
