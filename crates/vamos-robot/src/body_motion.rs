//! The body-motion error `e_b` (REFERENCE.md section 2): how far the observed motion of
//! the robot's body departs from the motion its joint states predict.
//!
//! `e_b = |med(O^J_x) - med(O_x)| + |med(O^J_y) - med(O_y)|`, the medians taken over the
//! body mask, where `O^J` is the expected body flow (from [`crate::render`]) and
//! `O` the observed flow (TV-L1 `t-1 -> t`), both forward flow in pixels. Each median
//! skips `NaN` values of its own component and field (the rendered flow is `NaN` in the
//! mask's margin, where no surface was drawn). When any of the four medians has no value
//! (the body is not visible, or only `NaN` under the mask) `e_b` is 0 and
//! [`BodyMotion::body_visible`] is false.
//!
//! Imports only [`vamos_vision::image`].

use vamos_vision::image::FlowField;

/// Errors of the body-motion error.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BodyMotionError {
    /// The fields and the mask do not have the same number of pixels.
    #[error(
        "size mismatch: expected flow {expected_width}x{expected_height}, observed flow {observed_width}x{observed_height}, mask of {mask_len} pixels"
    )]
    SizeMismatch {
        /// Width of the expected flow.
        expected_width: usize,
        /// Height of the expected flow.
        expected_height: usize,
        /// Width of the observed flow.
        observed_width: usize,
        /// Height of the observed flow.
        observed_height: usize,
        /// Pixels in the mask.
        mask_len: usize,
    },
}

/// `e_b` with what it was computed from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BodyMotion {
    /// The error, pixels (0 when the body is not visible).
    pub e_b_px: f64,
    /// Median of the expected flow over the mask, `(x, y)` pixels (`NaN` when none).
    pub expected_median_px: [f64; 2],
    /// Median of the observed flow over the mask, `(x, y)` pixels (`NaN` when none).
    pub observed_median_px: [f64; 2],
    /// Pixels in the mask.
    pub mask_pixels: usize,
    /// False when the mask is empty or a median had no finite value.
    pub body_visible: bool,
}

/// Computes `e_b` over the pixels where `mask` is true (see the module docs).
pub fn body_motion_error(
    expected: &FlowField,
    observed: &FlowField,
    mask: &[bool],
) -> Result<BodyMotion, BodyMotionError> {
    if expected.size() != observed.size() || mask.len() != expected.u.len() {
        return Err(BodyMotionError::SizeMismatch {
            expected_width: expected.width(),
            expected_height: expected.height(),
            observed_width: observed.width(),
            observed_height: observed.height(),
            mask_len: mask.len(),
        });
    }
    let mask_pixels = mask.iter().filter(|&&m| m).count();
    let mut scratch = Vec::with_capacity(mask_pixels);
    let mut median = |values: &[f32]| masked_median(values, mask, &mut scratch);
    let expected_median_px = [median(&expected.u), median(&expected.v)];
    let observed_median_px = [median(&observed.u), median(&observed.v)];
    let body_visible = expected_median_px
        .iter()
        .chain(&observed_median_px)
        .all(|m| m.is_finite());
    let e_b_px = if body_visible {
        (expected_median_px[0] - observed_median_px[0]).abs()
            + (expected_median_px[1] - observed_median_px[1]).abs()
    } else {
        0.0
    };
    Ok(BodyMotion {
        e_b_px,
        expected_median_px,
        observed_median_px,
        mask_pixels,
        body_visible,
    })
}

/// Median of the finite `values` where `mask` is true (mean of the two middle values for
/// an even count); `NaN` when there are none.
fn masked_median(values: &[f32], mask: &[bool], scratch: &mut Vec<f32>) -> f64 {
    scratch.clear();
    scratch.extend(
        values
            .iter()
            .zip(mask)
            .filter(|(v, m)| **m && v.is_finite())
            .map(|(v, _)| *v),
    );
    let n = scratch.len();
    if n == 0 {
        return f64::NAN;
    }
    let (_, upper, _) = scratch.select_nth_unstable_by(n / 2, f32::total_cmp);
    let upper = f64::from(*upper);
    if n % 2 == 1 {
        return upper;
    }
    // The lower middle is the largest of the first n/2 values.
    let lower = scratch[..n / 2]
        .iter()
        .copied()
        .fold(f32::NEG_INFINITY, f32::max);
    (f64::from(lower) + upper) / 2.0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn medians_and_error_on_a_constructed_field() {
        let (w, h) = (4, 3);
        // Expected: u = x, v = -y; observed: u = 2x + 1, v = 0.5.
        let expected = FlowField::from_fn(w, h, |x, y| (x as f32, -(y as f32)));
        let observed = FlowField::from_fn(w, h, |x, _| (2.0 * x as f32 + 1.0, 0.5));
        // Mask: columns 1..=3 of rows 0 and 1 (6 pixels).
        let mask: Vec<bool> = (0..w * h).map(|i| i % w >= 1 && i / w <= 1).collect();
        let r = body_motion_error(&expected, &observed, &mask).unwrap();
        assert_eq!(r.mask_pixels, 6);
        assert!(r.body_visible);
        // Expected u over mask: {1,2,3,1,2,3} -> median 2; v: {0,0,0,-1,-1,-1} -> -0.5.
        assert_eq!(r.expected_median_px, [2.0, -0.5]);
        // Observed u: {3,5,7,3,5,7} -> 5; v: 0.5.
        assert_eq!(r.observed_median_px, [5.0, 0.5]);
        assert_eq!(r.e_b_px, 3.0 + 1.0);
    }

    #[test]
    fn nan_values_are_skipped_and_outliers_do_not_move_the_median() {
        let u = vec![1.0, f32::NAN, 2.0, 100.0, 3.0];
        let v = vec![0.0, 0.0, f32::NAN, f32::NAN, 0.0];
        let expected = FlowField::new(5, 1, u, v).unwrap();
        let observed = FlowField::zeros(5, 1);
        let r = body_motion_error(&expected, &observed, &[true; 5]).unwrap();
        // u: {1, 2, 100, 3} -> (2 + 3) / 2; v: {0, 0, 0} -> 0.
        assert_eq!(r.expected_median_px, [2.5, 0.0]);
        assert_eq!(r.e_b_px, 2.5);
    }

    #[test]
    fn empty_mask_reports_an_invisible_body() {
        let f = FlowField::from_fn(3, 2, |_, _| (1.0, 1.0));
        let g = FlowField::zeros(3, 2);
        let r = body_motion_error(&f, &g, &[false; 6]).unwrap();
        assert!(!r.body_visible);
        assert_eq!(r.e_b_px, 0.0);
        assert_eq!(r.mask_pixels, 0);
        assert!(r.expected_median_px[0].is_nan());
        // All-NaN expected flow under a non-empty mask: also not visible.
        let nan = FlowField::from_fn(3, 2, |_, _| (f32::NAN, f32::NAN));
        let r = body_motion_error(&nan, &g, &[true; 6]).unwrap();
        assert!(!r.body_visible && r.e_b_px == 0.0 && r.mask_pixels == 6);
    }

    #[test]
    fn size_mismatch_is_an_error() {
        let f = FlowField::zeros(3, 2);
        let g = FlowField::zeros(2, 3);
        assert!(matches!(
            body_motion_error(&f, &g, &[true; 6]),
            Err(BodyMotionError::SizeMismatch { .. })
        ));
        assert!(matches!(
            body_motion_error(&f, &f, &[true; 5]),
            Err(BodyMotionError::SizeMismatch { mask_len: 5, .. })
        ));
    }
}
