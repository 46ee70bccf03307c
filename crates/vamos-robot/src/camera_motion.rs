//! Expected camera motion: the 2-D similarity the kinematics predicts between two frames,
//! and the camera-motion error `e_c` against the registered (observed) one.
//!
//! From `camera_from_base` at `t-1` and `t`, the intrinsics `K` and a depth (a constant
//! assumed depth in metres, or a depth image of frame `t-1`), a grid of pixels of frame
//! `t-1` is lifted to 3-D, moved into the camera of frame `t`, projected again, and a 2-D
//! similarity is fitted to the correspondences by linear least squares (REFERENCE.md
//! section 1; Hartley and Zisserman eq. 9.6/9.7 give the same points in closed form).
//!
//! The result is a [`Similarity`] in exactly the convention of the registration
//! (`vision::registration`): it maps frame `t-1` onto frame `t` about the image centre
//! `((w-1)/2, (h-1)/2)`, rotation counter-clockwise on screen positive. So
//! `e_c = |tx - tx'| + |ty - ty'|` compares like with like;
//! `tests/integration/camera_motion.rs` renders a textured plane seen by a moving camera,
//! registers it and checks the two agree.

use super::camera::Intrinsics;
use nalgebra::{Isometry3, Point2, Point3};
use serde::{Deserialize, Serialize};
use vamos_vision::FlowField;
use vamos_vision::registration::Similarity;

/// Parameters of the expected-camera-motion fit.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct CameraMotionParams {
    /// Depth assumed for every grid point when no depth image is given (or where it has
    /// no valid value), metres along the optical axis. The reference code used 0.5 m; a
    /// head camera looking at a work surface sees most texture at about 1 m.
    pub assumed_depth_m: f64,
    /// Grid points across the image.
    pub grid_columns: usize,
    /// Grid points down the image.
    pub grid_rows: usize,
    /// Calibration learns the static scene's depth per cell of a `grid_columns x
    /// grid_rows` grid from the training frames (the flow the camera's translation gives
    /// it), used instead of `assumed_depth_m` wherever no depth image comes: for a camera
    /// that moves, not only turns, and has no depth image. Needs the scene detector.
    pub learn_depth: bool,
}

impl Default for CameraMotionParams {
    fn default() -> Self {
        Self {
            assumed_depth_m: 1.0,
            grid_columns: 16,
            grid_rows: 12,
            learn_depth: false,
        }
    }
}

/// Where the depth of the grid points comes from.
#[derive(Debug, Clone, Copy)]
pub enum Depth<'a> {
    /// [`CameraMotionParams::assumed_depth_m`] everywhere.
    Assumed,
    /// A depth image of frame `t-1` at the intrinsics' resolution, metres along the
    /// optical axis, row-major; values that are not finite or not positive fall back to
    /// the assumed depth.
    Image(&'a [f32]),
}

/// Errors of the camera-motion fit.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum CameraMotionError {
    /// A parameter is out of range.
    #[error("camera motion parameter {name} = {value} is invalid ({reason})")]
    InvalidParams {
        /// Parameter name.
        name: &'static str,
        /// Its value.
        value: f64,
        /// What is wrong.
        reason: &'static str,
    },
    /// A pose contains NaN or infinity.
    #[error("the {which} camera pose is not finite")]
    NonFinitePose {
        /// `previous` or `current`.
        which: &'static str,
    },
    /// The depth image does not match the intrinsics' size.
    #[error("depth image has {len} values, expected {width}x{height}")]
    DepthSize {
        /// Values given.
        len: usize,
        /// Expected width.
        width: u32,
        /// Expected height.
        height: u32,
    },
    /// Fewer than three grid points stayed in front of the camera.
    #[error("only {points} grid points are in front of the camera after the motion; need 3")]
    TooFewPoints {
        /// Points that could be used.
        points: usize,
    },
}

/// The expected motion of the image between two frames.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ExpectedCameraMotion {
    /// The fitted similarity (registration convention).
    pub transform: Similarity,
    /// Root-mean-square distance between the projected points and the fitted similarity,
    /// pixels: how well a similarity describes this motion (large for strong translation
    /// over varying depth or large out-of-plane rotation).
    pub residual_rms_px: f64,
    /// Grid points used in the fit.
    pub points: usize,
}

/// The expected flow `t-1 -> t` of every static pixel of frame `t-1` (the source grid,
/// as TV-L1 indexes its output) from the two camera poses (`camera_from_base`, optical):
/// the pixel's ray at its depth along the optical axis carried into the current camera
/// and projected. The depth is the pixel's in `depth` (a depth image of frame `t-1` at
/// the intrinsics' resolution), else `assumed_depth_m`. The rotation part is exact
/// whatever the depth (`K R K^-1`); only the translation part depends on it. A point that
/// ends behind the camera gets NaN. `out` is resized to the intrinsics' size.
pub fn expected_image_flow(
    previous_camera_from_base: &Isometry3<f64>,
    current_camera_from_base: &Isometry3<f64>,
    intrinsics: &Intrinsics,
    depth: Depth<'_>,
    assumed_depth_m: f64,
    out: &mut FlowField,
) -> Result<(), CameraMotionError> {
    if !(assumed_depth_m.is_finite() && assumed_depth_m > 0.0) {
        return Err(CameraMotionError::InvalidParams {
            name: "assumed_depth_m",
            value: assumed_depth_m,
            reason: "must be a finite depth > 0",
        });
    }
    for (which, pose) in [
        ("previous", previous_camera_from_base),
        ("current", current_camera_from_base),
    ] {
        if !is_finite(pose) {
            return Err(CameraMotionError::NonFinitePose { which });
        }
    }
    let (w, h) = (intrinsics.width as usize, intrinsics.height as usize);
    let depth_image = match depth {
        Depth::Assumed => None,
        Depth::Image(d) if d.len() == w * h => Some(d),
        Depth::Image(d) => {
            return Err(CameraMotionError::DepthSize {
                len: d.len(),
                width: intrinsics.width,
                height: intrinsics.height,
            });
        }
    };
    if out.size() != (w, h) {
        *out = FlowField::zeros(w, h);
    }
    let current_from_previous = current_camera_from_base * previous_camera_from_base.inverse();
    let r = current_from_previous
        .rotation
        .to_rotation_matrix()
        .into_inner();
    let t = current_from_previous.translation.vector;
    let k = intrinsics;
    for y in 0..h {
        let ry = (y as f64 - k.cy) / k.fy;
        for x in 0..w {
            let rx = (x as f64 - k.cx) / k.fx;
            let i = y * w + x;
            let depth_m = depth_image
                .map(|d| f64::from(d[i]))
                .filter(|z| z.is_finite() && *z > 0.0)
                .unwrap_or(assumed_depth_m);
            // P' = R (z r) + t, r = (rx, ry, 1).
            let px = depth_m * (r[(0, 0)] * rx + r[(0, 1)] * ry + r[(0, 2)]) + t.x;
            let py = depth_m * (r[(1, 0)] * rx + r[(1, 1)] * ry + r[(1, 2)]) + t.y;
            let pz = depth_m * (r[(2, 0)] * rx + r[(2, 1)] * ry + r[(2, 2)]) + t.z;
            if pz > 0.0 {
                out.u[i] = (k.fx * px / pz + k.cx - x as f64) as f32;
                out.v[i] = (k.fy * py / pz + k.cy - y as f64) as f32;
            } else {
                out.u[i] = f32::NAN;
                out.v[i] = f32::NAN;
            }
        }
    }
    Ok(())
}

/// The flow `t-1 -> t` of every pixel under a registered similarity (the image motion
/// the registration saw), on the source grid; `out` is resized to `width x height`.
pub fn similarity_flow(transform: &Similarity, width: usize, height: usize, out: &mut FlowField) {
    if out.size() != (width, height) {
        *out = FlowField::zeros(width, height);
    }
    let centre = ((width as f64 - 1.0) / 2.0, (height as f64 - 1.0) / 2.0);
    let (s, c) = transform.rotation_deg.to_radians().sin_cos();
    let sc = transform.scale;
    for y in 0..height {
        let dy = y as f64 - centre.1;
        for x in 0..width {
            let dx = x as f64 - centre.0;
            let i = y * width + x;
            out.u[i] = (sc * (c * dx + s * dy) + transform.tx_px - dx) as f32;
            out.v[i] = (sc * (-s * dx + c * dy) + transform.ty_px - dy) as f32;
        }
    }
}

/// Predicts the image motion from the camera poses of frames `t-1` (`previous`) and `t`
/// (`current`), both `camera_from_base` in the optical convention.
pub fn expected_camera_motion(
    previous_camera_from_base: &Isometry3<f64>,
    current_camera_from_base: &Isometry3<f64>,
    intrinsics: &Intrinsics,
    depth: Depth<'_>,
    params: &CameraMotionParams,
) -> Result<ExpectedCameraMotion, CameraMotionError> {
    validate(params)?;
    for (which, pose) in [
        ("previous", previous_camera_from_base),
        ("current", current_camera_from_base),
    ] {
        if !is_finite(pose) {
            return Err(CameraMotionError::NonFinitePose { which });
        }
    }
    let (w, h) = (intrinsics.width, intrinsics.height);
    if let Depth::Image(d) = depth
        && d.len() != w as usize * h as usize
    {
        return Err(CameraMotionError::DepthSize {
            len: d.len(),
            width: w,
            height: h,
        });
    }
    // Maps points of the previous camera frame into the current one.
    let current_from_previous = current_camera_from_base * previous_camera_from_base.inverse();
    let centre = Point2::new((f64::from(w) - 1.0) / 2.0, (f64::from(h) - 1.0) / 2.0);
    let mut pairs = Vec::with_capacity(params.grid_columns * params.grid_rows);
    for row in 0..params.grid_rows {
        for col in 0..params.grid_columns {
            // Cell centres of a regular grid over the image.
            let x = (col as f64 + 0.5) / params.grid_columns as f64 * f64::from(w) - 0.5;
            let y = (row as f64 + 0.5) / params.grid_rows as f64 * f64::from(h) - 0.5;
            let z = match depth {
                Depth::Assumed => params.assumed_depth_m,
                Depth::Image(d) => {
                    let (xi, yi) = (x.round() as usize, y.round() as usize);
                    let v =
                        f64::from(d[yi.min(h as usize - 1) * w as usize + xi.min(w as usize - 1)]);
                    if v.is_finite() && v > 0.0 {
                        v
                    } else {
                        params.assumed_depth_m
                    }
                }
            };
            let p = Point2::new(x, y);
            let moved = current_from_previous * intrinsics.backproject(&p, z);
            if let Some(q) = intrinsics.project(&moved)
                && q.x.is_finite()
                && q.y.is_finite()
            {
                pairs.push((p - centre, q - centre));
            }
        }
    }
    fit_similarity(&pairs)
}

/// Least-squares similarity `q = s R p + t` (registration convention) to centred pairs.
fn fit_similarity(
    pairs: &[(nalgebra::Vector2<f64>, nalgebra::Vector2<f64>)],
) -> Result<ExpectedCameraMotion, CameraMotionError> {
    if pairs.len() < 3 {
        return Err(CameraMotionError::TooFewPoints {
            points: pairs.len(),
        });
    }
    let n = pairs.len() as f64;
    let (pm, qm) = pairs.iter().fold(
        (nalgebra::Vector2::zeros(), nalgebra::Vector2::zeros()),
        |(a, b), (p, q)| (a + p / n, b + q / n),
    );
    // Model: q = [[a, b], [-b, a]] p + t with a = s cos(r), b = s sin(r); see
    // `synthetic::similarity_forward`. The normal equations decouple after centring.
    let (mut sa, mut sb, mut sd) = (0.0, 0.0, 0.0);
    for (p, q) in pairs {
        let (d, e) = (p - pm, q - qm);
        sa += d.x * e.x + d.y * e.y;
        sb += d.y * e.x - d.x * e.y;
        sd += d.norm_squared();
    }
    let (a, b) = if sd > 0.0 {
        (sa / sd, sb / sd)
    } else {
        (1.0, 0.0)
    };
    let apply =
        |p: &nalgebra::Vector2<f64>| nalgebra::Vector2::new(a * p.x + b * p.y, -b * p.x + a * p.y);
    let t = qm - apply(&pm);
    let residual = pairs
        .iter()
        .map(|(p, q)| (apply(p) + t - q).norm_squared())
        .sum::<f64>()
        / n;
    Ok(ExpectedCameraMotion {
        transform: Similarity {
            tx_px: t.x,
            ty_px: t.y,
            scale: a.hypot(b),
            rotation_deg: b.atan2(a).to_degrees(),
        },
        residual_rms_px: residual.sqrt(),
        points: pairs.len(),
    })
}

/// Weights of the camera-motion error.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct CameraErrorWeights {
    /// Pixels of error per degree of rotation difference (0 = the paper's `e_c`).
    pub rotation_px_per_deg: f64,
    /// Pixels of error per unit of relative scale difference (0 = the paper's `e_c`).
    pub scale_px: f64,
}

impl Default for CameraErrorWeights {
    fn default() -> Self {
        Self {
            rotation_px_per_deg: 0.0,
            scale_px: 0.0,
        }
    }
}

/// `e_c = |tx - tx'| + |ty - ty'|` (REFERENCE.md section 1), plus the optional weighted
/// rotation and relative scale differences. NaN in either transform gives NaN (the caller
/// decides what an unusable frame scores).
pub fn camera_motion_error(
    expected: &Similarity,
    observed: &Similarity,
    weights: &CameraErrorWeights,
) -> f64 {
    let rotation = {
        let d = (expected.rotation_deg - observed.rotation_deg).rem_euclid(360.0);
        d.min(360.0 - d)
    };
    (expected.tx_px - observed.tx_px).abs()
        + (expected.ty_px - observed.ty_px).abs()
        + weights.rotation_px_per_deg * rotation
        + weights.scale_px * (expected.scale / observed.scale - 1.0).abs()
}

fn validate(params: &CameraMotionParams) -> Result<(), CameraMotionError> {
    if !(params.assumed_depth_m.is_finite() && params.assumed_depth_m > 0.0) {
        return Err(CameraMotionError::InvalidParams {
            name: "assumed_depth_m",
            value: params.assumed_depth_m,
            reason: "must be a positive number of metres",
        });
    }
    for (name, value) in [
        ("grid_columns", params.grid_columns),
        ("grid_rows", params.grid_rows),
    ] {
        if !(2..=1024).contains(&value) {
            return Err(CameraMotionError::InvalidParams {
                name,
                value: value as f64,
                reason: "must be in 2..=1024",
            });
        }
    }
    Ok(())
}

fn is_finite(pose: &Isometry3<f64>) -> bool {
    pose.translation.vector.iter().all(|v| v.is_finite())
        && pose.rotation.coords.iter().all(|v| v.is_finite())
}

/// A point `p` of the previous frame seen at depth `depth_m`: where it appears in the
/// current frame (closed form, Hartley and Zisserman eq. 9.7). `None` when it ends up
/// behind the camera. Useful for checks and for drawing the expected motion.
pub fn transfer_point(
    current_from_previous: &Isometry3<f64>,
    intrinsics: &Intrinsics,
    p: &Point2<f64>,
    depth_m: f64,
) -> Option<Point2<f64>> {
    let x: Point3<f64> = intrinsics.backproject(p, depth_m);
    intrinsics.project(&(current_from_previous * x))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion, Vector3};

    fn camera() -> Intrinsics {
        // Principal point at the image centre, so a roll about the optical axis is a
        // rotation about the registration's centre.
        Intrinsics::new(320, 240, 300.0, 300.0, 159.5, 119.5).unwrap()
    }

    /// `camera_from_base` poses for a camera that starts at the base origin and then
    /// moves by `previous_from_current` (the current camera's pose in the previous one).
    fn poses(previous_from_current: Isometry3<f64>) -> (Isometry3<f64>, Isometry3<f64>) {
        (Isometry3::identity(), previous_from_current.inverse())
    }

    fn predict(previous_from_current: Isometry3<f64>) -> ExpectedCameraMotion {
        let (a, b) = poses(previous_from_current);
        expected_camera_motion(
            &a,
            &b,
            &camera(),
            Depth::Assumed,
            &CameraMotionParams::default(),
        )
        .unwrap()
    }

    #[test]
    fn no_motion_is_identity() {
        let m = predict(Isometry3::identity());
        assert!(m.transform.difference(&Similarity::IDENTITY).0 < 1e-12);
        assert!(m.residual_rms_px < 1e-12);
        assert_eq!(m.points, 16 * 12);
    }

    #[test]
    fn sideways_translation_shifts_the_image_the_other_way() {
        // The camera moves 5 cm to its right (+x optical) and 2 cm down (+y) at 1 m depth:
        // the scene moves left by f * 0.05 / 1 = 15 px and up by 6 px (H&Z eq. 9.6).
        let m = predict(Isometry3::translation(0.05, 0.02, 0.0));
        let t = m.transform;
        assert!((t.tx_px + 15.0).abs() < 1e-9, "{t:?}");
        assert!((t.ty_px + 6.0).abs() < 1e-9, "{t:?}");
        assert!((t.scale - 1.0).abs() < 1e-12 && t.rotation_deg.abs() < 1e-9);
        assert!(m.residual_rms_px < 1e-9);
    }

    #[test]
    fn forward_translation_is_a_scale() {
        // Moving 0.2 m towards a plane at 1 m magnifies it by 1 / 0.8 about the principal
        // point.
        let m = predict(Isometry3::translation(0.0, 0.0, 0.2));
        assert!((m.transform.scale - 1.25).abs() < 1e-12, "{m:?}");
        assert!(m.transform.tx_px.abs() < 1e-9 && m.transform.ty_px.abs() < 1e-9);
        assert!(m.transform.rotation_deg.abs() < 1e-9);
    }

    #[test]
    fn roll_about_the_optical_axis_is_a_rotation() {
        // The camera turns by +4 degrees about its optical axis (z forward): from the
        // camera's view, x (right) turns towards y (down), i.e. clockwise on screen, so
        // the scene appears to turn counter-clockwise on screen: +4 degrees in the
        // registration's convention.
        let roll = Isometry3::from_parts(
            Translation3::identity(),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 4f64.to_radians()),
        );
        let m = predict(roll);
        assert!((m.transform.rotation_deg - 4.0).abs() < 1e-9, "{m:?}");
        assert!((m.transform.scale - 1.0).abs() < 1e-12);
        assert!(m.transform.tx_px.abs() < 1e-9 && m.transform.ty_px.abs() < 1e-9);
    }

    #[test]
    fn pan_is_close_to_a_translation_of_f_tan_angle() {
        // Turning right by 2 degrees (about optical +y, which points down) moves the
        // centre of the image left by f tan(2 deg); the whole motion is a homography,
        // which a similarity only approximates.
        let pan = Isometry3::from_parts(
            Translation3::identity(),
            UnitQuaternion::from_axis_angle(&Vector3::y_axis(), 2f64.to_radians()),
        );
        let m = predict(pan);
        let expected = -300.0 * 2f64.to_radians().tan();
        // Off-centre points move farther (x' = f tan(atan(x / f) - angle)), so the fitted
        // shift is a little larger than the centre's; the fit reports the misfit.
        let t = m.transform;
        assert!(
            t.tx_px < expected && t.tx_px > expected * 1.15,
            "{m:?} vs {expected}"
        );
        assert!(t.ty_px.abs() < 1e-9 && t.rotation_deg.abs() < 1e-9);
        assert!(m.residual_rms_px > 0.5 && m.residual_rms_px < 2.0, "{m:?}");
        // The closed-form transfer of the centre pixel is exactly f tan(angle).
        let (a, b) = poses(pan);
        let q = transfer_point(
            &(b * a.inverse()),
            &camera(),
            &Point2::new(159.5, 119.5),
            1.0,
        )
        .unwrap();
        assert!((q.x - 159.5 - expected).abs() < 1e-9);
    }

    #[test]
    fn the_expected_image_flow_takes_each_pixels_depth_from_the_depth_image() {
        // The camera moves 5 cm to its right: a pixel at depth z moves by -f 0.05 / z.
        let (a, b) = poses(Isometry3::translation(0.05, 0.0, 0.0));
        let k = camera();
        let (w, h) = (320, 240);
        // The left half at 0.5 m, the right half at 2 m, one hole (0) and one NaN.
        let mut depth: Vec<f32> = (0..w * h)
            .map(|i| if i % w < w / 2 { 0.5 } else { 2.0 })
            .collect();
        depth[10] = 0.0;
        depth[w + 10] = f32::NAN;
        let mut flow = FlowField::zeros(0, 0);
        expected_image_flow(&a, &b, &k, Depth::Image(&depth), 1.0, &mut flow).unwrap();
        assert_eq!(flow.size(), (w, h));
        for (x, y, z) in [(20, 100, 0.5), (300, 100, 2.0), (10, 0, 1.0), (10, 1, 1.0)] {
            let (u, v) = flow.get(x, y);
            assert!(
                (f64::from(u) + 300.0 * 0.05 / z).abs() < 1e-3,
                "({x},{y}) {u}"
            );
            assert!(v.abs() < 1e-4);
        }
        // The same motion without a depth image: the assumed depth everywhere.
        let mut assumed = FlowField::zeros(0, 0);
        expected_image_flow(&a, &b, &k, Depth::Assumed, 2.0, &mut assumed).unwrap();
        assert!((f64::from(assumed.get(20, 100).0) + 7.5).abs() < 1e-3);
        // A depth image of another size is refused, naming both sizes.
        let err =
            expected_image_flow(&a, &b, &k, Depth::Image(&depth[1..]), 1.0, &mut flow).unwrap_err();
        assert!(err.to_string().contains("320x240"), "{err}");
    }

    #[test]
    fn combined_motion_matches_the_composition_of_its_parts() {
        // Roll, forward and sideways translation: the image of a fronto-parallel plane
        // moves by an exact similarity. Scale = Z / (Z - tz); the rotation is the roll; a
        // sideways move of the camera by (tx, ty) expressed in the *new* camera shifts the
        // image by -f (tx, ty) / (Z - tz).
        let roll = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), (-3f64).to_radians());
        let motion = Isometry3::from_parts(Translation3::new(0.03, -0.01, 0.1), roll);
        let m = predict(motion);
        let t = m.transform;
        assert!((t.scale - 1.0 / 0.9).abs() < 1e-12, "{t:?}");
        assert!((t.rotation_deg + 3.0).abs() < 1e-9, "{t:?}");
        // Translation of the previous camera's origin seen from the new camera.
        let shift = roll.inverse() * Vector3::new(0.03, -0.01, 0.0);
        assert!((t.tx_px + 300.0 * shift.x / 0.9).abs() < 1e-9, "{t:?}");
        assert!((t.ty_px + 300.0 * shift.y / 0.9).abs() < 1e-9, "{t:?}");
        assert!(m.residual_rms_px < 1e-9);
    }

    #[test]
    fn depth_image_overrides_the_assumed_depth() {
        let (a, b) = poses(Isometry3::translation(0.05, 0.0, 0.0));
        let k = camera();
        let depth = vec![2.0f32; 320 * 240];
        let m = expected_camera_motion(
            &a,
            &b,
            &k,
            Depth::Image(&depth),
            &CameraMotionParams::default(),
        )
        .unwrap();
        assert!((m.transform.tx_px + 7.5).abs() < 1e-9, "{m:?}");
        // Invalid depth values fall back to the assumed depth (1 m): -15 px.
        let invalid = vec![f32::NAN; 320 * 240];
        let m = expected_camera_motion(
            &a,
            &b,
            &k,
            Depth::Image(&invalid),
            &CameraMotionParams::default(),
        )
        .unwrap();
        assert!((m.transform.tx_px + 15.0).abs() < 1e-9, "{m:?}");
    }

    #[test]
    fn bad_input_is_an_error() {
        let k = camera();
        let id = Isometry3::identity();
        let params = CameraMotionParams::default();
        let mut nan = id;
        nan.translation.vector.x = f64::NAN;
        assert_eq!(
            expected_camera_motion(&nan, &id, &k, Depth::Assumed, &params),
            Err(CameraMotionError::NonFinitePose { which: "previous" })
        );
        assert!(matches!(
            expected_camera_motion(&id, &id, &k, Depth::Image(&[1.0; 5]), &params),
            Err(CameraMotionError::DepthSize { len: 5, .. })
        ));
        let bad = CameraMotionParams {
            assumed_depth_m: 0.0,
            ..params.clone()
        };
        assert!(matches!(
            expected_camera_motion(&id, &id, &k, Depth::Assumed, &bad),
            Err(CameraMotionError::InvalidParams {
                name: "assumed_depth_m",
                ..
            })
        ));
        // The camera passes the plane: every point ends behind it.
        let through = Isometry3::translation(0.0, 0.0, 2.0);
        assert!(matches!(
            expected_camera_motion(&id, &through.inverse(), &k, Depth::Assumed, &params),
            Err(CameraMotionError::TooFewPoints { points: 0 })
        ));
    }

    #[test]
    fn e_c_is_the_translation_l1_plus_optional_terms() {
        let a = Similarity {
            tx_px: 1.0,
            ty_px: -2.0,
            scale: 1.1,
            rotation_deg: 179.0,
        };
        let b = Similarity {
            tx_px: -0.5,
            ty_px: 1.0,
            scale: 1.0,
            rotation_deg: -179.0,
        };
        assert!((camera_motion_error(&a, &b, &CameraErrorWeights::default()) - 4.5).abs() < 1e-12);
        let w = CameraErrorWeights {
            rotation_px_per_deg: 2.0,
            scale_px: 10.0,
        };
        // Rotation difference wraps to 2 degrees; scale differs by 10 %.
        assert!((camera_motion_error(&a, &b, &w) - (4.5 + 4.0 + 1.0)).abs() < 1e-9);
    }
}
