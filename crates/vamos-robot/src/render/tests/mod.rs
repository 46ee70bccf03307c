//! Tests of the render module against analytic expectations (boxes at known poses, rays
//! intersected with boxes independently of the rasteriser).

mod flow;
mod inputs;
mod raster;

use super::shapes::{SyntheticArm, cuboid};
use super::*;
use nalgebra::{Point2, Point3, Translation3, UnitQuaternion};

fn k320() -> Intrinsics {
    Intrinsics::new(320, 240, 300.0, 300.0, 159.5, 119.5).unwrap()
}

fn at(x: f64, y: f64, z: f64) -> Isometry3<f64> {
    Isometry3::from_parts(Translation3::new(x, y, z), UnitQuaternion::identity())
}

fn renderer(config: RenderConfig, meshes: &[LinkMesh]) -> CpuRenderer {
    let mut r = CpuRenderer::new(&config).unwrap();
    r.prepare(meshes).unwrap();
    r
}

fn render(
    r: &mut CpuRenderer,
    k: &Intrinsics,
    current: RobotView<'_>,
    previous: Option<RobotView<'_>>,
) -> RenderOutput {
    let mut out = RenderOutput::default();
    r.render(
        &RenderFrame {
            intrinsics: k,
            current,
            previous,
            shade: false,
        },
        &mut out,
    )
    .unwrap();
    out
}

fn box_mesh(link: usize, half: [f32; 3]) -> LinkMesh {
    LinkMesh {
        link,
        mesh: cuboid(half),
    }
}

/// Covered pixels as a bounding rectangle `(x_min, x_max, y_min, y_max)` and the count.
fn bbox(out: &RenderOutput, pixels: &[bool]) -> ((usize, usize, usize, usize), usize) {
    let mut b = (usize::MAX, 0, usize::MAX, 0);
    let mut n = 0;
    for (i, _) in pixels.iter().enumerate().filter(|(_, c)| **c) {
        let (x, y) = (i % out.width, i / out.width);
        b = (b.0.min(x), b.1.max(x), b.2.min(y), b.3.max(y));
        n += 1;
    }
    (b, n)
}

/// Ray from the camera centre through `pixel`, intersected with the box of half
/// extents `half` at `camera_from_box`; returns the point in the box frame (slab method).
fn ray_box(
    k: &Intrinsics,
    pixel: Point2<f64>,
    camera_from_box: &Isometry3<f64>,
    half: [f64; 3],
) -> Option<Point3<f64>> {
    let dir_c = k.backproject(&pixel, 1.0).coords;
    let box_from_camera = camera_from_box.inverse();
    let o = box_from_camera * Point3::origin();
    let d = box_from_camera * dir_c;
    let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
    for a in 0..3 {
        let (lo, hi) = ((-half[a] - o[a]) / d[a], (half[a] - o[a]) / d[a]);
        t0 = t0.max(lo.min(hi));
        t1 = t1.min(lo.max(hi));
    }
    (t0 <= t1).then(|| o + d * t0)
}
