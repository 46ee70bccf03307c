//! A depth of the static scene learned from nominal frames, for a camera that moves
//! without a depth image (issue "detection beyond the paper", item 1).
//!
//! The static scene's expected flow is exact for the camera's rotation (`K R K^-1`) but its
//! translation part scales with each pixel's inverse depth `rho = 1 / z`. Linearised at
//! `rho = 0` (a point at infinity), a static pixel's flow is
//!
//! ```text
//! f(p) ~= r(p) + rho(p) j(p),   r: the rotation's flow,
//!                               j = (fx (t_x a_z - a_x t_z), fy (t_y a_z - a_y t_z)) / a_z^2
//! ```
//!
//! with `a = R K^-1 p` the pixel's rotated ray and `t` the camera's translation between
//! the frames. Each nominal frame gives, per cell of a coarse grid, the least-squares
//! `rho` of its static pixels across image edges (the normal flow, as the scene residual
//! measures it: `(f_obs - r) . g = rho j . g`, `g` the image gradient) with the weight
//! `sum (j . g)^2`, which is zero when the camera did not translate
//! ([`depth_evidence`]); calibration fits the depth from them
//! ([`crate::eval::depth::LearnedDepth`]).
//!
//! The depth is in the image's coordinates, so it is learned per view of the camera (see
//! `eval::depth`). A camera that only turns (a head on a pan-tilt unit) gives no evidence
//! and keeps the assumed depth; a depth image (`[topics] depth`) wins over the learned
//! depth wherever it comes.

use super::residual::gradient;
pub use crate::eval::depth::{DepthEvidence, LearnedDepth, ViewIndex};
use nalgebra::Isometry3;
use vamos_robot::Intrinsics;
use vamos_vision::{FlowField, GrayImage};

/// The cell of pixel `(x, y)` on a `columns x rows` grid over `w x h`.
fn cell_of(x: usize, y: usize, (w, h): (usize, usize), (columns, rows): (usize, usize)) -> usize {
    (y * rows / h) * columns + x * columns / w
}

/// One frame's depth evidence (see the module doc): `observed` is the TV-L1 flow from
/// the frame whose pose is `previous` (camera from base) to the one at `current`,
/// `source` the image it starts from, `exclude` the pixels that are not static scene (the
/// robot and what it carries, grown); `grid` the cells `(columns, rows)`.
pub fn depth_evidence(
    previous: &Isometry3<f64>,
    current: &Isometry3<f64>,
    k: &Intrinsics,
    observed: &FlowField,
    source: &GrayImage,
    exclude: &[bool],
    grid: (usize, usize),
) -> DepthEvidence {
    let (w, h) = observed.size();
    let cells = grid.0 * grid.1;
    let mut jj = vec![0.0f64; cells];
    let mut jd = vec![0.0f64; cells];
    let usable = source.size() == (w, h) && w >= 3 && h >= 3 && cells > 0;
    let img = source.data();
    let motion = current * previous.inverse();
    let r = motion.rotation.to_rotation_matrix().into_inner();
    let t = motion.translation.vector;
    for y in (0..h).filter(|_| usable) {
        let ry = (y as f64 - k.cy) / k.fy;
        for x in 0..w {
            let i = y * w + x;
            if exclude.get(i).copied().unwrap_or(false) {
                continue;
            }
            let rx = (x as f64 - k.cx) / k.fx;
            let ax = r[(0, 0)] * rx + r[(0, 1)] * ry + r[(0, 2)];
            let ay = r[(1, 0)] * rx + r[(1, 1)] * ry + r[(1, 2)];
            let az = r[(2, 0)] * rx + r[(2, 1)] * ry + r[(2, 2)];
            if az <= 1e-6 {
                continue;
            }
            let ru = k.fx * ax / az + k.cx - x as f64;
            let rv = k.fy * ay / az + k.cy - y as f64;
            let ju = k.fx * (t.x * az - ax * t.z) / (az * az);
            let jv = k.fy * (t.y * az - ay * t.z) / (az * az);
            let (gx, gy) = gradient(img, w, h, x, y);
            let (gx, gy) = (f64::from(gx), f64::from(gy));
            let a = ju * gx + jv * gy;
            let b = (f64::from(observed.u[i]) - ru) * gx + (f64::from(observed.v[i]) - rv) * gy;
            if a.is_finite() && b.is_finite() {
                let c = cell_of(x, y, (w, h), grid);
                jj[c] += a * a;
                jd[c] += a * b;
            }
        }
    }
    DepthEvidence {
        camera_from_base: *previous,
        cell_rad: w as f64 / grid.0.max(1) as f64 / k.fx,
        cells: jj
            .iter()
            .zip(&jd)
            .map(|(&jj, &jd)| {
                if jj > 1e-12 {
                    [(jd / jj) as f32, jj as f32]
                } else {
                    [0.0, 0.0]
                }
            })
            .collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    /// A camera translating sideways in front of a textured wall at `depth_m` (the
    /// observed flow is the wall's exact flow): every cell learns the wall's depth.
    #[test]
    fn a_translating_camera_learns_the_wall_depth() {
        let (w, h) = (64usize, 48usize);
        let k = Intrinsics::new(w as u32, h as u32, 60.0, 60.0, 31.5, 23.5).unwrap();
        let depth_m = 0.6;
        let image: Vec<f32> = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f32, (i / w) as f32);
                128.0 + 60.0 * (0.7 * x).sin() + 50.0 * (0.45 * y + 0.3 * x).cos()
            })
            .collect();
        let source = GrayImage::new(w, h, image).unwrap();
        let previous = Isometry3::identity();
        // The evidence of a frame whose camera moved to `current` before a wall at `wall_m`.
        let evidence_of = |current: &Isometry3<f64>, wall_m: f64| {
            let mut flow = FlowField::zeros(w, h);
            vamos_robot::camera_motion::expected_image_flow(
                &previous,
                current,
                &k,
                vamos_robot::camera_motion::Depth::Assumed,
                wall_m,
                &mut flow,
            )
            .unwrap();
            depth_evidence(&previous, current, &k, &flow, &source, &[], (4, 3))
        };
        // The camera moves sideways and turns a little: in the camera frame the static
        // world moves the other way.
        let evidence: Vec<DepthEvidence> = [0.01, -0.015, 0.02]
            .iter()
            .map(|step| {
                let current = Isometry3::from_parts(
                    Translation3::new(-step, 0.003, 0.0),
                    UnitQuaternion::from_euler_angles(0.0, 0.01, 0.0),
                );
                evidence_of(&current, depth_m)
            })
            .collect();
        let learned = LearnedDepth::fit(&evidence, (4, 3)).unwrap();
        assert_eq!((learned.frames, learned.filled_cells), (3, 0));
        for (i, rho) in learned.inverse_depth.iter().enumerate() {
            let d = 1.0 / rho;
            assert!((d - 0.6).abs() < 0.03, "cell {i}: {d} m");
        }
        learned.validate().unwrap();
        let pixels = learned.pixel_depths(None, w, h);
        assert_eq!(pixels.len(), w * h);
        assert!(pixels.iter().all(|d| (d - 0.6).abs() < 0.03));
        // A camera that only turns says nothing about depth.
        let turn = Isometry3::from_parts(
            Translation3::identity(),
            UnitQuaternion::from_euler_angles(0.0, 0.02, 0.0),
        );
        let e = evidence_of(&turn, 1.0);
        assert!(e.cells.iter().all(|p| p[1] == 0.0), "{e:?}");
        assert!(LearnedDepth::fit(&[e], (4, 3)).is_err());
    }
}
