//! The static scene's depth learned from nominal frames' evidence (calibration maths of
//! `[pipeline.camera_motion] learn_depth`; the per-frame evidence is measured by
//! `pipeline::depth`, whose module doc gives the model).
//!
//! A cell's inverse depth is the weighted median of the frames' least-squares estimates
//! (robust to the frames where something moved there). It is learned per *view*: the
//! frames are grouped by the camera's pose in the robot's base frame, two poses being close
//! when the image moves by less than about a cell between them (the rotation angle plus
//! the translation over the median depth, radians), at most [`MAX_VIEWS`] groups. A frame
//! takes the depth of the view nearest its camera pose, or the depth of all frames pooled
//! when none is near; cells with little evidence take the pooled depth (and pooled cells
//! with little evidence the median of all).

use nalgebra::{Isometry3, Point3, Quaternion, UnitQuaternion};
use serde::{Deserialize, Serialize};

/// The nearest depth a cell may learn, metres.
pub const MIN_DEPTH_M: f32 = 0.05;
/// The farthest depth a cell may learn, metres (a cell whose pixels do not move with
/// the translation at all is "far").
pub const MAX_DEPTH_M: f32 = 100.0;
/// A cell whose evidence is below this share of the median cell's (among the cells with
/// any) takes the median of all cells.
const MIN_EVIDENCE_SHARE: f64 = 0.05;

/// At most this many views (groups of nearby camera poses); with more, the views grow.
pub const MAX_VIEWS: usize = 64;
/// A view needs this many training frames.
const MIN_VIEW_FRAMES: usize = 3;

/// One frame's evidence on the static scene's depth.
#[derive(Debug, Clone, PartialEq)]
pub struct DepthEvidence {
    /// The camera's pose (camera from base) in the frame the flow starts from: the frame
    /// whose pixels the depth is of.
    pub camera_from_base: Isometry3<f64>,
    /// The angular width of a grid cell, radians.
    pub cell_rad: f64,
    /// Per cell, `(rho, weight)` with `rho` in 1/m; weight 0 where the frame says nothing
    /// (no static pixel, no edge, no translation).
    pub cells: Vec<[f32; 2]>,
}

/// The learned depth of the static scene seen from one group of nearby camera poses.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct DepthView {
    /// The camera's optical centre in the base frame, metres.
    pub position: [f64; 3],
    /// The camera's orientation (camera from base), a unit quaternion `[w, x, y, z]`.
    pub orientation: [f64; 4],
    /// Inverse depth per cell, 1/m, row-major.
    pub inverse_depth: Vec<f32>,
    /// Training frames in the view.
    pub frames: usize,
}

/// The learned depth of the static scene: one inverse depth per cell of a
/// `columns x rows` grid over the processing image, per view and over all of them.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct LearnedDepth {
    /// Cells across.
    pub columns: usize,
    /// Cells down.
    pub rows: usize,
    /// Inverse depth per cell over every view, 1/m, row-major (a frame far from every
    /// view takes it).
    pub inverse_depth: Vec<f32>,
    /// The views (groups of nearby camera poses) with their own depths.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub views: Vec<DepthView>,
    /// Camera poses within this distance of a view's (radians: the rotation angle plus
    /// the translation over the median depth) are in it; a frame within twice of the
    /// nearest view takes its depth.
    #[serde(default)]
    pub view_radius_rad: f64,
    /// Cells with too little evidence of their own (they took the median of all cells).
    pub filled_cells: usize,
    /// Training frames that gave evidence.
    pub frames: usize,
}

/// The weighted median of `(value, weight)` pairs with positive weight; `None` without any.
fn weighted_median(pairs: &mut [[f32; 2]]) -> Option<f32> {
    let total: f64 = pairs.iter().map(|p| f64::from(p[1])).sum();
    if total <= 0.0 {
        return None;
    }
    pairs.sort_by(|a, b| a[0].total_cmp(&b[0]));
    let mut acc = 0.0;
    for p in pairs.iter() {
        acc += f64::from(p[1]);
        if acc >= total / 2.0 {
            return Some(p[0]);
        }
    }
    pairs.last().map(|p| p[0])
}

/// A camera pose as a view keeps it: the optical centre in the base frame and the
/// orientation (camera from base).
type ViewPose = (Point3<f64>, UnitQuaternion<f64>);

/// A camera pose (camera from base) as a [`ViewPose`].
fn view_pose(camera_from_base: &Isometry3<f64>) -> ViewPose {
    (
        camera_from_base.inverse_transform_point(&Point3::origin()),
        camera_from_base.rotation,
    )
}

/// How far apart two camera poses are as the image sees it, radians: the rotation angle
/// plus the distance between the optical centres times the median inverse depth.
fn pose_distance(a: &ViewPose, b: &ViewPose, inverse_depth: f64) -> f64 {
    a.1.angle_to(&b.1) + (a.0 - b.0).norm() * inverse_depth
}

/// The place in `poses` of the one nearest `pose` ([`pose_distance`]) within `limit`.
fn nearest_within<'a>(
    pose: &ViewPose,
    poses: impl Iterator<Item = &'a ViewPose>,
    inverse_depth: f64,
    limit: f64,
) -> Option<usize> {
    poses
        .enumerate()
        .map(|(i, p)| (i, pose_distance(pose, p, inverse_depth)))
        .filter(|(_, d)| *d <= limit)
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(i, _)| i)
}

/// A learned depth's views ready for lookup ([`LearnedDepth::view_index`]).
#[derive(Debug, Clone)]
pub struct ViewIndex {
    poses: Vec<ViewPose>,
    inverse_depth: f64,
    limit: f64,
}

impl ViewIndex {
    /// The view whose depth a frame with this camera pose (camera from base) takes: the
    /// nearest within twice the view radius; `None`: the depth over every view.
    pub fn nearest(&self, camera_from_base: &Isometry3<f64>) -> Option<usize> {
        nearest_within(
            &view_pose(camera_from_base),
            self.poses.iter(),
            self.inverse_depth,
            self.limit,
        )
    }
}

/// The weighted median per cell of the given frames' evidence; `None` for a cell whose
/// evidence weighs less than `min_weight`.
fn cell_medians(frames: &[&DepthEvidence], cells: usize, min_weight: f64) -> Vec<Option<f32>> {
    (0..cells)
        .map(|c| {
            let mut pairs: Vec<[f32; 2]> = frames
                .iter()
                .map(|e| e.cells[c])
                .filter(|p| p[1] > 0.0 && p[0].is_finite() && p[1].is_finite())
                .collect();
            let weight: f64 = pairs.iter().map(|p| f64::from(p[1])).sum();
            (weight > 0.0 && weight >= min_weight)
                .then(|| weighted_median(&mut pairs))
                .flatten()
        })
        .collect()
}

/// Each cell of a `(columns, rows)` map replaced by the median of its 3x3 neighbourhood
/// (fewer at the border): a cell that disagrees with all its neighbours was measured
/// wrong (something moved there, the flow failed), a surface is smooth.
fn median_3x3(map: &[f32], (columns, rows): (usize, usize)) -> Vec<f32> {
    let mut out = Vec::with_capacity(map.len());
    let mut near = Vec::with_capacity(9);
    for y in 0..rows {
        for x in 0..columns {
            near.clear();
            for ny in y.saturating_sub(1)..(y + 2).min(rows) {
                for nx in x.saturating_sub(1)..(x + 2).min(columns) {
                    near.push(map[ny * columns + nx]);
                }
            }
            near.sort_by(f32::total_cmp);
            out.push(near[near.len() / 2]);
        }
    }
    out
}

/// The median of `values` (NaN when empty).
fn median_f32(values: &[f32]) -> f32 {
    let mut v = values.to_vec();
    v.sort_by(f32::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(f32::NAN)
}

/// The median of the positive values (0 without any).
fn median_positive(values: impl IntoIterator<Item = f64>) -> f64 {
    let mut v: Vec<f64> = values.into_iter().filter(|w| *w > 0.0).collect();
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(0.0)
}

impl LearnedDepth {
    /// Fits the learned depth on a `grid` from the training frames' evidence (frames of
    /// another grid size are left out). Errors (with the reason) when no frame shows the
    /// camera translating past an edge of the static scene.
    pub fn fit<'a>(
        evidence: impl IntoIterator<Item = &'a DepthEvidence>,
        grid: (usize, usize),
    ) -> Result<Self, String> {
        let cells = grid.0 * grid.1;
        let frames: Vec<&DepthEvidence> = evidence
            .into_iter()
            .filter(|e| e.cells.len() == cells && e.cells.iter().any(|p| p[1] > 0.0))
            .collect();
        let cell_weight = |frames: &[&DepthEvidence], c: usize| -> f64 {
            frames
                .iter()
                .map(|e| f64::from(e.cells[c][1]))
                .filter(|w| w.is_finite())
                .sum()
        };
        let median_weight = median_positive((0..cells).map(|c| cell_weight(&frames, c)));
        if frames.is_empty() || median_weight <= 0.0 {
            return Err(
                "no training frame shows the camera translating past an edge of the \
                        static scene: there is no depth to learn (a fixed or only turning \
                        camera needs none)"
                    .into(),
            );
        }
        let (lo, hi) = (1.0 / MAX_DEPTH_M, 1.0 / MIN_DEPTH_M);
        // Every frame pooled; cells with too little evidence take the median of all.
        let pooled = cell_medians(&frames, cells, MIN_EVIDENCE_SHARE * median_weight);
        let mut all: Vec<[f32; 2]> = frames
            .iter()
            .flat_map(|e| e.cells.iter().copied())
            .filter(|p| p[1] > 0.0 && p[0].is_finite() && p[1].is_finite())
            .collect();
        let overall = weighted_median(&mut all).unwrap_or(1.0).clamp(lo, hi);
        let filled_cells = pooled.iter().filter(|v| v.is_none()).count();
        let inverse_depth = median_3x3(
            &pooled
                .iter()
                .map(|v| v.unwrap_or(overall).clamp(lo, hi))
                .collect::<Vec<_>>(),
            grid,
        );
        // The views: nearby camera poses grouped (leader clustering in frame order), the
        // radius grown until at most MAX_VIEWS groups remain.
        let poses: Vec<_> = frames
            .iter()
            .map(|e| view_pose(&e.camera_from_base))
            .collect();
        let mut cell_rads: Vec<f64> = frames.iter().map(|e| e.cell_rad).collect();
        cell_rads.sort_by(f64::total_cmp);
        let mut radius = cell_rads[cell_rads.len() / 2];
        if !(radius.is_finite() && radius > 0.0) {
            radius = 0.01;
        }
        let rho = f64::from(median_f32(&inverse_depth));
        let (leaders, members) = loop {
            let mut leaders: Vec<usize> = Vec::new();
            let mut members: Vec<Vec<usize>> = Vec::new();
            for (i, pose) in poses.iter().enumerate() {
                match nearest_within(pose, leaders.iter().map(|&l| &poses[l]), rho, radius) {
                    Some(v) => members[v].push(i),
                    None => {
                        leaders.push(i);
                        members.push(vec![i]);
                    }
                }
            }
            if leaders.len() <= MAX_VIEWS {
                break (leaders, members);
            }
            radius *= 1.5;
        };
        let groups: Vec<Vec<&DepthEvidence>> = members
            .iter()
            .map(|m| m.iter().map(|&i| frames[i]).collect())
            .collect();
        // A view's cell needs a twentieth of a typical view cell's evidence; each map is
        // smoothed by a 3x3 median.
        let view_weight = median_positive(
            groups
                .iter()
                .flat_map(|g| (0..cells).map(move |c| cell_weight(g, c))),
        );
        let views = leaders
            .iter()
            .zip(&groups)
            .filter(|(_, g)| g.len() >= MIN_VIEW_FRAMES)
            .map(|(&l, g)| {
                let own = cell_medians(g, cells, MIN_EVIDENCE_SHARE * view_weight);
                let (position, orientation) = poses[l];
                let q = orientation.quaternion();
                DepthView {
                    position: [position.x, position.y, position.z],
                    orientation: [q.w, q.i, q.j, q.k],
                    inverse_depth: median_3x3(
                        &own.iter()
                            .zip(&inverse_depth)
                            .map(|(v, pooled)| v.unwrap_or(*pooled).clamp(lo, hi))
                            .collect::<Vec<_>>(),
                        grid,
                    ),
                    frames: g.len(),
                }
            })
            .collect();
        Ok(Self {
            columns: grid.0,
            rows: grid.1,
            inverse_depth,
            views,
            view_radius_rad: radius,
            filled_cells,
            frames: frames.len(),
        })
    }

    /// Refuses a learned depth no scorer can use (a stored calibration edited by hand).
    pub fn validate(&self) -> Result<(), String> {
        let cells = self.columns * self.rows;
        let (lo, hi) = (1.0 / MAX_DEPTH_M, 1.0 / MIN_DEPTH_M);
        if self.columns == 0 || self.rows == 0 || self.columns > 1024 || self.rows > 1024 {
            return Err(format!(
                "learned depth: a {}x{} grid",
                self.columns, self.rows
            ));
        }
        if self.views.len() > MAX_VIEWS {
            return Err(format!(
                "learned depth: {} views, at most {MAX_VIEWS}",
                self.views.len()
            ));
        }
        if !(self.view_radius_rad.is_finite() && self.view_radius_rad >= 0.0) {
            return Err(format!(
                "learned depth: view radius {}",
                self.view_radius_rad
            ));
        }
        let maps = std::iter::once(("every view", &self.inverse_depth))
            .chain(self.views.iter().map(|v| ("a view", &v.inverse_depth)));
        for (which, map) in maps {
            if map.len() != cells {
                return Err(format!(
                    "learned depth ({which}): {} values for a {}x{} grid",
                    map.len(),
                    self.columns,
                    self.rows
                ));
            }
            if let Some(v) = map.iter().find(|v| !(lo..=hi).contains(*v)) {
                return Err(format!(
                    "learned depth ({which}): inverse depth {v} 1/m outside [{lo}, {hi}]"
                ));
            }
        }
        for v in &self.views {
            let norm = v.orientation.iter().map(|x| x * x).sum::<f64>().sqrt();
            let unit = (norm - 1.0).abs() < 1e-3; // false for NaN too
            if !v.position.iter().all(|x| x.is_finite()) || !unit {
                return Err("learned depth: a view's position or orientation is not a pose".into());
            }
        }
        Ok(())
    }

    /// The views' poses ready for lookup: build it once, then ask [`ViewIndex::nearest`]
    /// per frame.
    pub fn view_index(&self) -> ViewIndex {
        ViewIndex {
            poses: self
                .views
                .iter()
                .map(|v| {
                    let [w, x, y, z] = v.orientation;
                    let q = UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z));
                    (Point3::from(v.position), q)
                })
                .collect(),
            inverse_depth: f64::from(median_f32(&self.inverse_depth)),
            limit: 2.0 * self.view_radius_rad,
        }
    }

    /// The view whose depth a frame with this camera pose (camera from base) takes (see
    /// [`ViewIndex::nearest`]).
    pub fn view_for(&self, camera_from_base: &Isometry3<f64>) -> Option<usize> {
        self.view_index().nearest(camera_from_base)
    }

    /// The depth of every pixel of a `w x h` image, metres, row-major, in `view` (or over
    /// every view): the cells' inverse depths interpolated bilinearly between the cells'
    /// centres.
    pub fn pixel_depths(&self, view: Option<usize>, w: usize, h: usize) -> Vec<f32> {
        let map = view
            .and_then(|v| self.views.get(v))
            .map_or(&self.inverse_depth, |v| &v.inverse_depth);
        let (c, r) = (self.columns, self.rows);
        let at = |cx: usize, cy: usize| map[cy * c + cx];
        // The continuous cell coordinate of a pixel centre, clamped to the centres.
        let coord = |p: usize, n: usize, cells: usize| {
            let v =
                ((p as f32 + 0.5) * cells as f32 / n as f32 - 0.5).clamp(0.0, (cells - 1) as f32);
            let i = (v.floor() as usize).min(cells.saturating_sub(2));
            (i, (v - i as f32).clamp(0.0, 1.0))
        };
        let mut out = Vec::with_capacity(w * h);
        for y in 0..h {
            let (y0, fy) = coord(y, h, r);
            let y1 = (y0 + 1).min(r - 1);
            for x in 0..w {
                let (x0, fx) = coord(x, w, c);
                let x1 = (x0 + 1).min(c - 1);
                let top = at(x0, y0) * (1.0 - fx) + at(x1, y0) * fx;
                let bottom = at(x0, y1) * (1.0 - fx) + at(x1, y1) * fx;
                out.push(1.0 / (top * (1.0 - fy) + bottom * fy));
            }
        }
        out
    }

    /// The median, nearest and farthest depth over every view, metres.
    pub fn summary(&self) -> (f32, f32, f32) {
        let mut d: Vec<f32> = self.inverse_depth.iter().map(|v| 1.0 / v).collect();
        d.sort_by(f32::total_cmp);
        (
            median_f32(&d),
            d.first().copied().unwrap_or(f32::NAN),
            d.last().copied().unwrap_or(f32::NAN),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_weighted_median_follows_the_weight() {
        let mut p = [[1.0, 1.0], [2.0, 5.0], [100.0, 1.0]];
        assert_eq!(weighted_median(&mut p), Some(2.0));
        assert_eq!(weighted_median(&mut []), None);
    }

    /// Synthetic evidence of one frame at `pose` with every cell at `rho`.
    fn evidence(pose: Isometry3<f64>, rho: f32, cells: usize) -> DepthEvidence {
        DepthEvidence {
            camera_from_base: pose,
            cell_rad: 0.05,
            cells: vec![[rho, 1.0]; cells],
        }
    }

    #[test]
    fn each_view_keeps_its_own_depth() {
        // Frames from two places 0.5 m apart: near a wall (0.25 m) and far from it (1 m),
        // in turn, each a little jittered.
        let near = |j: f64| Isometry3::translation(0.001 * j, 0.0, 0.0);
        let far = |j: f64| Isometry3::translation(0.001 * j, 0.0, -0.5);
        let frames: Vec<DepthEvidence> = (0..8)
            .flat_map(|j| {
                let j = f64::from(j);
                [evidence(near(j), 4.0, 6), evidence(far(j), 1.0, 6)]
            })
            .collect();
        let learned = LearnedDepth::fit(&frames, (3, 2)).unwrap();
        learned.validate().unwrap();
        assert_eq!(learned.views.len(), 2, "{learned:?}");
        assert_eq!(learned.views.iter().map(|v| v.frames).sum::<usize>(), 16);
        let depth_at = |pose: &Isometry3<f64>| {
            let v = learned.view_for(pose);
            (v, learned.pixel_depths(v, 6, 4)[0])
        };
        let (v_near, d_near) = depth_at(&near(2.5));
        let (v_far, d_far) = depth_at(&far(-3.0));
        assert!(v_near.is_some() && v_far.is_some() && v_near != v_far);
        assert_eq!((d_near, d_far), (0.25, 1.0));
        // Half-way, far from both: the depth of every frame pooled.
        let (v, _) = depth_at(&Isometry3::translation(0.0, 0.0, -0.25));
        assert_eq!(v, None);
        // A hand-edited view that is not a pose is refused.
        let mut bad = learned.clone();
        bad.views[0].orientation = [0.0; 4];
        assert!(bad.validate().is_err());
        // A view needs MIN_VIEW_FRAMES frames.
        let few = LearnedDepth::fit(&frames[..4], (3, 2)).unwrap();
        assert!(few.views.is_empty(), "{few:?}");
    }

    #[test]
    fn thin_cells_take_the_median_and_lone_outliers_are_smoothed_away() {
        // A 3x3 grid at 0.5 m but for one cell with almost no evidence (at 0.125 m) and
        // one well measured at 10 m (something moved there).
        let mut cells = vec![[2.0, 10.0]; 9];
        cells[0] = [8.0, 0.01];
        cells[4] = [0.1, 10.0];
        let frame = DepthEvidence {
            camera_from_base: Isometry3::identity(),
            cell_rad: 0.1,
            cells,
        };
        let learned = LearnedDepth::fit(&[frame.clone(), frame], (3, 3)).unwrap();
        assert_eq!(learned.filled_cells, 1);
        assert_eq!(learned.inverse_depth, vec![2.0; 9]);
        assert_eq!(
            median_3x3(&[1.0, 5.0, 2.0, 3.0], (4, 1)),
            [5.0, 2.0, 3.0, 3.0]
        );
    }

    #[test]
    fn depths_interpolate_between_cells_and_bad_maps_are_refused() {
        // Between the centres of the first two cells the inverse depth is linear.
        let d = LearnedDepth {
            columns: 2,
            rows: 1,
            inverse_depth: vec![1.0, 2.0],
            views: Vec::new(),
            view_radius_rad: 0.1,
            filled_cells: 0,
            frames: 1,
        };
        let px = d.pixel_depths(None, 4, 1);
        assert_eq!(px[0], 1.0);
        assert_eq!(px[3], 0.5);
        assert!((1.0 / px[1] - 1.25).abs() < 1e-6 && (1.0 / px[2] - 1.75).abs() < 1e-6);
        let mut bad = d.clone();
        bad.inverse_depth[0] = 0.0;
        assert!(bad.validate().is_err());
        bad.inverse_depth.pop();
        assert!(bad.validate().is_err());
    }
}
