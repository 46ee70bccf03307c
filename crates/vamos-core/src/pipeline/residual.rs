//! Per-pixel residuals between the motion a frame shows and the motion the robot's
//! kinematics predict (issue "detection beyond the paper"):
//!
//! - **Scene** (`e_r`): outside the robot, every static pixel moves only with the camera.
//!   The expected flow of the whole image comes from the two camera poses
//!   ([`vamos_robot::camera_motion::expected_image_flow`]; the registered similarity when
//!   there is no pose), the residual `|observed - expected|` is averaged per cell of a
//!   coarse grid ([`scene_cells`]), and the cells are normalised by their nominal
//!   statistics and pooled over the few worst ([`crate::eval::pool_cells`]), so a small
//!   falling object counts however still the rest of the scene is. The robot (both frames'
//!   masks, grown by `margin_px`) is left out: its motion is the body detector's.
//! - **Body** (`e_b`, `body_error = "quantile"`): per pixel of the rendered robot, the
//!   observed flow where that surface point was at `t-1` against its exact rendered flow;
//!   a high quantile over the pixels that move (expected or observed) says whether the
//!   moving part of the robot moves as its joint states say, however much of the robot is
//!   still. The paper's median `e_b` stays as `body_error = "median"`.

use serde::{Deserialize, Serialize};
use vamos_vision::{FlowField, GrayImage};

/// How `e_b` compares expected and observed body motion.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum BodyError {
    /// The paper: medians of both flows over the mask.
    #[default]
    Median,
    /// A high quantile of the per-pixel residual over the moving pixels.
    Quantile,
}

/// How `e_o` pools the flow predictor's per-pixel error.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum FlowPooling {
    /// The paper: the mean squared error over the valid pixels of the `S x S` map.
    #[default]
    Mean,
    /// The error averaged per cell ([`flow_cells`]), each cell normalised by its nominal
    /// statistics once calibrated, and the worst few pooled as for `e_r`: a small object
    /// moving where nothing should counts, however well the rest is predicted.
    Cells,
}

/// The `[pipeline.residual]` settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct ResidualParams {
    /// Side of a scene cell, pixels at the processing resolution.
    pub cell_px: usize,
    /// The robot's masks are grown by this many pixels before the scene residual is taken
    /// (TV-L1 spreads a moving edge's flow over a few pixels around it)...
    pub margin_px: usize,
    /// ... plus this many times the robot's own motion this frame (the 95th percentile of
    /// its rendered flow, pixels): coarse-to-fine flow smears a boundary about as far as
    /// it moves.
    pub motion_margin: f64,
    /// Share of the valid cells whose mean is `e_r` (at least one cell).
    pub top_fraction: f64,
    /// Scene residual across image edges only (the normal flow), weighted by gradient;
    /// false: the whole flow difference.
    pub normal_flow: bool,
    /// With `normal_flow`: a pixel's residual is at most the brightness change the
    /// expected flow leaves (the images' own word on whether the static scene's motion
    /// explains it), so TV-L1's errors on repeated textures are not taken for motion.
    pub photometric: bool,
    /// How `e_b` is computed.
    pub body_error: BodyError,
    /// Quantile of the per-pixel body residual (`body_error = "quantile"`).
    pub body_quantile: f64,
    /// A body pixel counts as moving when its expected or observed flow is at least this
    /// long, pixels.
    pub moving_px: f64,
    /// Per-cell statistics per phase of the task, in windows this many seconds wide
    /// (a frame's phase: seconds since the stream's or episode's first image); 0: the
    /// same statistics at every phase.
    pub phase_window_s: f64,
    /// How `e_o` pools the predictor's error map.
    pub flow_pooling: FlowPooling,
    /// Side of an `e_o` cell, pixels of the network's `S x S` input
    /// (`flow_pooling = "cells"`).
    pub flow_cell_px: usize,
}

impl Default for ResidualParams {
    fn default() -> Self {
        Self {
            cell_px: 8,
            margin_px: 3,
            motion_margin: 0.0,
            top_fraction: 0.01,
            normal_flow: true,
            photometric: true,
            body_error: BodyError::Median,
            body_quantile: 0.9,
            moving_px: 0.5,
            phase_window_s: 0.0,
            flow_pooling: FlowPooling::Mean,
            flow_cell_px: 4,
        }
    }
}

impl ResidualParams {
    /// Whether scene maps are taken with the photometric check (it needs `normal_flow`).
    pub fn takes_photometric(&self) -> bool {
        self.normal_flow && self.photometric
    }

    /// Refuses values no residual can be computed with.
    pub fn validate(&self) -> Result<(), String> {
        if self.cell_px == 0 || self.cell_px > 256 {
            return Err(format!(
                "residual.cell_px = {} must lie in 1..=256",
                self.cell_px
            ));
        }
        if self.flow_cell_px == 0 || self.flow_cell_px > 64 {
            return Err(format!(
                "residual.flow_cell_px = {} must lie in 1..=64",
                self.flow_cell_px
            ));
        }
        if self.margin_px > 64 {
            return Err(format!(
                "residual.margin_px = {} is above the limit of 64",
                self.margin_px
            ));
        }
        for (name, v) in [
            ("top_fraction", self.top_fraction),
            ("body_quantile", self.body_quantile),
        ] {
            if !(0.0..=1.0).contains(&v) {
                return Err(format!("residual.{name} = {v} must lie in [0, 1]"));
            }
        }
        if !(self.motion_margin.is_finite() && (0.0..=16.0).contains(&self.motion_margin)) {
            return Err(format!(
                "residual.motion_margin = {} must lie in [0, 16]",
                self.motion_margin
            ));
        }
        if !self.moving_px.is_finite() || self.moving_px < 0.0 {
            return Err(format!(
                "residual.moving_px = {} must be a finite number >= 0",
                self.moving_px
            ));
        }
        if !(self.phase_window_s.is_finite() && (0.0..=600.0).contains(&self.phase_window_s)) {
            return Err(format!(
                "residual.phase_window_s = {} must lie in [0, 600]",
                self.phase_window_s
            ));
        }
        Ok(())
    }
}

/// Cells across and down for an image of `width x height` with cells of `cell_px`
/// (partial cells at the right and bottom edges count).
pub fn cell_grid(width: usize, height: usize, cell_px: usize) -> (usize, usize) {
    (width.div_ceil(cell_px), height.div_ceil(cell_px))
}

/// `out = a | b`, grown by `margin` pixels (a square), for row-major masks of
/// `width x height`. `b` may be empty (only `a`).
pub fn grow_union(a: &[bool], b: &[bool], width: usize, height: usize, margin: usize) -> Vec<bool> {
    let n = width * height;
    let mut base: Vec<bool> = (0..n)
        .map(|i| a.get(i).copied().unwrap_or(false) || b.get(i).copied().unwrap_or(false))
        .collect();
    if margin == 0 || n == 0 {
        return base;
    }
    // Rows then columns: a pixel is set when a set pixel lies within `margin` along the
    // pass's axis (running count over a window of 2 * margin + 1).
    let mut tmp = vec![false; n];
    for y in 0..height {
        dilate_line(
            &base[y * width..(y + 1) * width],
            &mut tmp[y * width..(y + 1) * width],
            margin,
        );
    }
    let mut column = vec![false; height];
    let mut grown = vec![false; height];
    for x in 0..width {
        for y in 0..height {
            column[y] = tmp[y * width + x];
        }
        dilate_line(&column, &mut grown, margin);
        for y in 0..height {
            base[y * width + x] = grown[y];
        }
    }
    base
}

fn dilate_line(src: &[bool], dst: &mut [bool], margin: usize) {
    let n = src.len();
    let mut count = 0usize;
    // Window [i - margin, i + margin]; start with [0, margin - 1] counted.
    for &v in src.iter().take(margin.min(n)) {
        count += usize::from(v);
    }
    for i in 0..n {
        if i + margin < n {
            count += usize::from(src[i + margin]);
        }
        if i > margin {
            count -= usize::from(src[i - margin - 1]);
        }
        dst[i] = count > 0;
    }
}

/// Per cell of `cell_px` pixels, over the pixels not in `exclude`, the residual
/// `d = observed - expected`:
/// - with `source` (the image the flow starts from): the *normal* residual, `|d . g|`
///   summed and divided by the summed `|g|` (`g` the image gradient): only the residual
///   across edges, which the flow measures, counts, weighted by how well it is measured.
///   Along an edge (stripes, a table's border) flow is ambiguous (the aperture problem)
///   and TV-L1's guess there is not evidence of motion; flat pixels weigh nothing;
/// - without: the mean of `|d|`.
///
/// With `target` too (the image the flow ends on), a pixel's normal residual is at most
/// the brightness change that the *expected* flow leaves, `|target(p + e) - source(p)|`:
/// where the images themselves say the static scene's motion explains the pixel, TV-L1's
/// disagreement (a wrong match on a repeated texture, its regulariser filling a flat
/// patch) is not evidence. Both are brightness differences, the first linearised, so
/// they compare directly; a pixel whose expected source lies outside `target` keeps the
/// flow's residual.
///
/// NaN for a cell with fewer than half of its pixels left, or no gradient at all.
/// Returns the map, row-major, [`cell_grid`] cells.
pub fn scene_cells(
    observed: &FlowField,
    expected: &FlowField,
    exclude: &[bool],
    cell_px: usize,
    source: Option<&GrayImage>,
    target: Option<&GrayImage>,
) -> Vec<f32> {
    let (w, h) = observed.size();
    let (cols, rows) = cell_grid(w, h, cell_px);
    let mut sum = vec![0.0f64; cols * rows];
    let mut weight = vec![0.0f64; cols * rows];
    let mut count = vec![0u32; cols * rows];
    let mut total = vec![0u32; cols * rows];
    let image = source.filter(|s| s.size() == (w, h)).map(GrayImage::data);
    let target = target.filter(|t| t.size() == (w, h));
    for y in 0..h {
        let row = (y / cell_px) * cols;
        for x in 0..w {
            let c = row + x / cell_px;
            total[c] += 1;
            let i = y * w + x;
            if exclude.get(i).copied().unwrap_or(false) {
                continue;
            }
            let du = observed.u[i] - expected.u[i];
            let dv = observed.v[i] - expected.v[i];
            let (r, wgt) = match image {
                Some(img) => {
                    let (gx, gy) = gradient(img, w, h, x, y);
                    let mut r = (du * gx + dv * gy).abs();
                    if let Some(change) = target.and_then(|t| {
                        sample_bilinear(t, x as f32 + expected.u[i], y as f32 + expected.v[i])
                    }) {
                        r = r.min((change - img[i]).abs());
                    }
                    (r, (gx * gx + gy * gy).sqrt())
                }
                None => ((du * du + dv * dv).sqrt(), 1.0),
            };
            if r.is_finite() && wgt.is_finite() {
                sum[c] += f64::from(r);
                weight[c] += f64::from(wgt);
                count[c] += 1;
            }
        }
    }
    (0..cols * rows)
        .map(|c| {
            if count[c] > 0 && 2 * count[c] >= total[c] && weight[c] > 1e-6 {
                (sum[c] / weight[c]) as f32
            } else {
                f32::NAN
            }
        })
        .collect()
}

/// The image gradient at `(x, y)` of a row-major `w x h` image: central differences,
/// one-sided at the border (0 along an axis of one pixel).
pub(crate) fn gradient(img: &[f32], w: usize, h: usize, x: usize, y: usize) -> (f32, f32) {
    let (x0, x1) = (x.saturating_sub(1), (x + 1).min(w - 1));
    let (y0, y1) = (y.saturating_sub(1), (y + 1).min(h - 1));
    (
        (img[y * w + x1] - img[y * w + x0]) / (x1 - x0).max(1) as f32,
        (img[y1 * w + x] - img[y0 * w + x]) / (y1 - y0).max(1) as f32,
    )
}

/// The flow predictor's `size x size` error map averaged per cell of `cell_px` (partial
/// cells at the edges count), over the pixels `valid` keeps (all without it); NaN for a
/// cell with fewer than half of its pixels valid. Row-major, [`cell_grid`] cells.
pub fn flow_cells(map: &[f32], valid: Option<&[bool]>, size: usize, cell_px: usize) -> Vec<f32> {
    let (cols, rows) = cell_grid(size, size, cell_px);
    let mut sum = vec![0.0f64; cols * rows];
    let mut count = vec![0u32; cols * rows];
    let mut total = vec![0u32; cols * rows];
    for (i, &e) in map.iter().enumerate().take(size * size) {
        let c = (i / size / cell_px) * cols + (i % size) / cell_px;
        total[c] += 1;
        if valid.is_none_or(|v| v.get(i).copied().unwrap_or(false)) && e.is_finite() {
            sum[c] += f64::from(e);
            count[c] += 1;
        }
    }
    (0..cols * rows)
        .map(|c| {
            if count[c] > 0 && 2 * count[c] >= total[c] {
                (sum[c] / f64::from(count[c])) as f32
            } else {
                f32::NAN
            }
        })
        .collect()
}

/// `image` at `(x, y)`, bilinear; `None` outside the pixel centres' hull or for a
/// non-finite position.
fn sample_bilinear(image: &GrayImage, x: f32, y: f32) -> Option<f32> {
    let (w, h) = image.size();
    if !(x >= 0.0 && y >= 0.0 && x <= (w - 1) as f32 && y <= (h - 1) as f32) {
        return None;
    }
    let (x0, y0) = (x.floor() as usize, y.floor() as usize);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let (tx, ty) = (x - x0 as f32, y - y0 as f32);
    let d = image.data();
    let top = d[y0 * w + x0] * (1.0 - tx) + d[y0 * w + x1] * tx;
    let bottom = d[y1 * w + x0] * (1.0 - tx) + d[y1 * w + x1] * tx;
    Some(top * (1.0 - ty) + bottom * ty)
}

/// The quantile body residual: for each pixel of `mask` with a finite rendered flow
/// `e` (target grid: the vector ends at the pixel), the observed flow at the pixel's
/// source `p - e` (bilinear) minus `e`; the `quantile` of its length over the pixels where
/// `|e|` or the observed flow is at least `moving_px`. `Some(0.0)` when the body is visible
/// but nothing on it moves; `None` when no pixel of the mask has a rendered flow.
pub fn body_residual(
    rendered: &FlowField,
    mask: &[bool],
    observed: &FlowField,
    quantile: f64,
    moving_px: f64,
) -> Option<f64> {
    let (w, h) = observed.size();
    if rendered.size() != (w, h) || mask.len() != w * h {
        return None;
    }
    let moving = moving_px as f32;
    let mut residuals = Vec::new();
    let mut visible = false;
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            if !mask[i] {
                continue;
            }
            let (eu, ev) = (rendered.u[i], rendered.v[i]);
            if !(eu.is_finite() && ev.is_finite()) {
                continue;
            }
            visible = true;
            let (sx, sy) = (x as f32 - eu, y as f32 - ev);
            let Some((ou, ov)) = sample(observed, sx, sy) else {
                continue;
            };
            let expected_len = (eu * eu + ev * ev).sqrt();
            let observed_len = (ou * ou + ov * ov).sqrt();
            if expected_len < moving && observed_len < moving {
                continue;
            }
            let (du, dv) = (ou - eu, ov - ev);
            residuals.push(f64::from((du * du + dv * dv).sqrt()));
        }
    }
    if !visible {
        return None;
    }
    if residuals.is_empty() {
        return Some(0.0);
    }
    residuals.sort_by(f64::total_cmp);
    Some(crate::eval::nominal::quantile_sorted(&residuals, quantile))
}

/// The 95th percentile of the length of the finite vectors of `flow` under `mask`
/// (0 when there are none): how far the robot moves this frame.
pub fn body_motion_px(flow: &FlowField, mask: &[bool]) -> f64 {
    let mut lengths: Vec<f64> = mask
        .iter()
        .enumerate()
        .filter(|&(_, &m)| m)
        .filter_map(|(i, _)| {
            let (u, v) = (flow.u.get(i)?, flow.v.get(i)?);
            let l = f64::from((u * u + v * v).sqrt());
            l.is_finite().then_some(l)
        })
        .collect();
    if lengths.is_empty() {
        return 0.0;
    }
    lengths.sort_by(f64::total_cmp);
    crate::eval::nominal::quantile_sorted(&lengths, 0.95)
}

/// Bilinear sample of a flow field at `(x, y)`; `None` outside the image.
fn sample(f: &FlowField, x: f32, y: f32) -> Option<(f32, f32)> {
    let (w, h) = f.size();
    if !(x >= 0.0 && y >= 0.0 && x <= (w - 1) as f32 && y <= (h - 1) as f32) {
        return None;
    }
    let (x0, y0) = (x.floor() as usize, y.floor() as usize);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let (fx, fy) = (x - x0 as f32, y - y0 as f32);
    let at = |plane: &[f32]| {
        let a = plane[y0 * w + x0] * (1.0 - fx) + plane[y0 * w + x1] * fx;
        let b = plane[y1 * w + x0] * (1.0 - fx) + plane[y1 * w + x1] * fx;
        a * (1.0 - fy) + b * fy
    };
    Some((at(&f.u), at(&f.v)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn growing_a_mask_is_a_square_dilation_of_the_union() {
        let (w, h) = (7, 5);
        let mut a = vec![false; w * h];
        let mut b = vec![false; w * h];
        a[2 * w + 1] = true;
        b[4 * w + 6] = true;
        let g = grow_union(&a, &b, w, h, 1);
        let set: Vec<(usize, usize)> = (0..w * h)
            .filter(|&i| g[i])
            .map(|i| (i % w, i / w))
            .collect();
        let mut expected = Vec::new();
        for y in 0..h {
            for x in 0..w {
                let near_a = x.abs_diff(1) <= 1 && y.abs_diff(2) <= 1;
                let near_b = x.abs_diff(6) <= 1 && y.abs_diff(4) <= 1;
                if near_a || near_b {
                    expected.push((x, y));
                }
            }
        }
        assert_eq!(set, expected);
        assert_eq!(grow_union(&a, &[], w, h, 0), a);
    }

    #[test]
    fn a_small_moving_patch_shows_in_its_cell_only() {
        let (w, h) = (32, 16);
        let expected = FlowField::from_fn(w, h, |_, _| (1.0, 0.0));
        // Everything moves as expected, except a 4x4 patch moving down by 3 px.
        let observed = FlowField::from_fn(w, h, |x, y| {
            if (20..24).contains(&x) && (4..8).contains(&y) {
                (1.0, 3.0)
            } else {
                (1.0, 0.0)
            }
        });
        let cells = scene_cells(&observed, &expected, &[], 8, None, None);
        assert_eq!(cells.len(), 4 * 2);
        assert_eq!(
            cells[2],
            3.0 * 16.0 / 64.0,
            "a quarter of cell (2, 0) moves"
        );
        assert!(cells.iter().enumerate().all(|(i, &c)| i == 2 || c == 0.0));
        // Excluding most of a cell leaves it without a value.
        let mut exclude = vec![false; w * h];
        for y in 0..8 {
            for x in 16..24 {
                exclude[y * w + x] = y < 5;
            }
        }
        let cells = scene_cells(&observed, &expected, &exclude, 8, None, None);
        // Normal residual: a patch of vertical stripes moving along them shows nothing;
        // across them it shows the full motion.
        let stripes = GrayImage::from_fn(w, h, |x, _| if x % 4 < 2 { 0.0 } else { 100.0 });
        let along = FlowField::from_fn(w, h, |_, _| (1.0, 3.0));
        let across = FlowField::from_fn(w, h, |_, _| (4.0, 0.0));
        let a = scene_cells(&along, &expected, &[], 8, Some(&stripes), None);
        let b = scene_cells(&across, &expected, &[], 8, Some(&stripes), None);
        assert!(a.iter().all(|&c| c == 0.0), "{a:?}");
        assert!(b.iter().all(|&c| (c - 3.0).abs() < 1e-5), "{b:?}");
        assert!(cells[2].is_nan());
    }

    #[test]
    fn the_photometric_check_drops_a_wrong_match_on_stripes_and_keeps_a_moving_patch() {
        let (w, h) = (32, 16);
        let still = FlowField::from_fn(w, h, |_, _| (0.0, 0.0));
        let stripes = |x: usize| if x % 4 < 2 { 0.0 } else { 100.0 };
        // Nothing moves, but the flow matched every stripe to the next one (4 px on).
        let image = GrayImage::from_fn(w, h, |x, _| stripes(x));
        let wrong = FlowField::from_fn(w, h, |_, _| (4.0, 0.0));
        let flow_only = scene_cells(&wrong, &still, &[], 8, Some(&image), None);
        assert!(
            flow_only.iter().all(|&c| (c - 4.0).abs() < 1e-5),
            "{flow_only:?}"
        );
        let checked = scene_cells(&wrong, &still, &[], 8, Some(&image), Some(&image));
        assert!(checked.iter().all(|&c| c == 0.0), "{checked:?}");

        // A bright 4x4 patch in cell (2, 0) moves down by 3 px, and the flow sees it.
        let patch =
            |x: usize, y: usize, top: usize| (20..24).contains(&x) && (top..top + 4).contains(&y);
        let before =
            GrayImage::from_fn(w, h, |x, y| if patch(x, y, 4) { 200.0 } else { stripes(x) });
        let after =
            GrayImage::from_fn(w, h, |x, y| if patch(x, y, 7) { 200.0 } else { stripes(x) });
        let seen = FlowField::from_fn(w, h, |x, y| {
            if patch(x, y, 4) {
                (0.0, 3.0)
            } else {
                (0.0, 0.0)
            }
        });
        let flow_only = scene_cells(&seen, &still, &[], 8, Some(&before), None);
        let checked = scene_cells(&seen, &still, &[], 8, Some(&before), Some(&after));
        // Smaller: a brightness change is bounded by the patch's contrast, where the
        // linearised flow residual grows with the motion.
        assert!(
            checked[2] > 0.25 * flow_only[2] && checked[2] < flow_only[2],
            "{checked:?} {flow_only:?}"
        );
        assert!(
            checked.iter().enumerate().all(|(i, &c)| i == 2 || c == 0.0),
            "{checked:?}"
        );
    }

    #[test]
    fn body_residual_sees_a_frozen_joint_however_still_the_rest_is() {
        let (w, h) = (40, 30);
        // A still base (the left fifth) and a 6x6 hand moving right by 2 px over the
        // background.
        let hand = |x: usize, y: usize| (10..16).contains(&x) && (10..16).contains(&y);
        let mask: Vec<bool> = (0..w * h)
            .map(|i| i % w < 8 || hand(i % w, i / w))
            .collect();
        let rendered = FlowField::from_fn(w, h, |x, y| {
            if hand(x, y) {
                (2.0, 0.0)
            } else if x < 8 {
                (0.0, 0.0)
            } else {
                (f32::NAN, f32::NAN)
            }
        });
        // Observed as expected: on the source grid the hand is 2 px further left.
        let good = FlowField::from_fn(w, h, |x, y| {
            if hand(x + 2, y) {
                (2.0, 0.0)
            } else {
                (0.0, 0.0)
            }
        });
        let frozen = FlowField::zeros(w, h);
        let ok = body_residual(&rendered, &mask, &good, 0.9, 0.5).unwrap();
        let bad = body_residual(&rendered, &mask, &frozen, 0.9, 0.5).unwrap();
        assert!(ok < 0.5, "as expected: {ok}");
        assert!((bad - 2.0).abs() < 1e-6, "frozen: {bad}");
        // The paper's medians see nothing: most of the body is still in both.
        let m = vamos_robot::body_motion::body_motion_error(&rendered, &frozen, &mask).unwrap();
        assert_eq!(m.e_b_px, 0.0);
        // Nothing visible: no value; visible but still: zero.
        assert_eq!(
            body_residual(&rendered, &vec![false; w * h], &frozen, 0.9, 0.5),
            None
        );
        let still = FlowField::zeros(w, h);
        assert_eq!(body_residual(&still, &mask, &still, 0.9, 0.5), Some(0.0));
    }

    #[test]
    fn parameters_out_of_range_are_refused() {
        assert!(ResidualParams::default().validate().is_ok());
        for p in [
            ResidualParams {
                cell_px: 0,
                ..Default::default()
            },
            ResidualParams {
                top_fraction: 1.5,
                ..Default::default()
            },
            ResidualParams {
                moving_px: f64::NAN,
                ..Default::default()
            },
        ] {
            assert!(p.validate().is_err());
        }
    }

    #[test]
    fn flow_cells_average_the_valid_pixels_of_each_cell() {
        // 4x4 map, 2x2 cells: the top-left cell holds the error, the bottom-right is
        // mostly masked.
        let mut map = vec![0.0f32; 16];
        map[0] = 4.0;
        let mut valid = vec![true; 16];
        for i in [10, 11, 14] {
            valid[i] = false;
        }
        let cells = flow_cells(&map, Some(&valid), 4, 2);
        assert_eq!(cells.len(), 4);
        assert_eq!(&cells[..3], &[1.0, 0.0, 0.0]);
        assert!(cells[3].is_nan(), "one valid pixel of four is too few");
        // A 5x5 map with 2-pixel cells: the edge cells are partial.
        let cells = flow_cells(&[1.0; 25], None, 5, 2);
        assert_eq!(cells, vec![1.0; 9]);
    }
}
