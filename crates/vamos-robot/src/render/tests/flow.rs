//! The exact flow: against ray casting for camera and link motion, and against TV-L1 of shaded renders.

use super::*;

/// Pixels whose 5x5 neighbourhood is covered: away from silhouette edges.
fn interior(out: &RenderOutput) -> Vec<(usize, usize)> {
    let (w, h) = (out.width, out.height);
    let mut v = Vec::new();
    for y in 2..h - 2 {
        for x in 2..w - 2 {
            if (0..5).all(|j| (0..5).all(|i| out.coverage[(y + j - 2) * w + x + i - 2])) {
                v.push((x, y));
            }
        }
    }
    v
}

#[test]
fn camera_moving_forward_gives_the_exact_radial_flow_on_both_grids() {
    let k = k320();
    let half = [0.2f32, 0.1, 0.05];
    let poses = [Isometry3::identity()];
    let prev = RobotView {
        camera_from_base: at(0.0, 0.0, 1.0),
        base_from_link: &poses,
    };
    let cur = RobotView {
        camera_from_base: at(0.0, 0.0, 0.9),
        base_from_link: &poses,
    };
    for grid in [FlowGrid::Target, FlowGrid::Source] {
        let config = RenderConfig {
            flow_grid: grid,
            ..RenderConfig::default()
        };
        let mut r = renderer(config, &[box_mesh(0, half)]);
        let out = render(&mut r, &k, cur, Some(prev));
        // Front face at depth 0.95 (t-1) and 0.85 (t). A point seen at pixel p at t was
        // at c + (p - c) * 0.85 / 0.95 at t-1; on the source grid, the point at p at t-1
        // goes to c + (p - c) * 0.95 / 0.85.
        let (scale, z) = match grid {
            FlowGrid::Target => (1.0 - 0.85 / 0.95, 0.85),
            FlowGrid::Source => (0.95 / 0.85 - 1.0, 0.95),
        };
        let px = interior(&out);
        assert!(px.len() > 5000, "{}", px.len());
        for &(x, y) in &px {
            let i = y * 320 + x;
            let (u, v) = out.flow.get(x, y);
            let eu = (x as f64 - 159.5) * scale;
            let ev = (y as f64 - 119.5) * scale;
            assert!(
                (f64::from(u) - eu).abs() < 1e-3,
                "{grid:?} ({x},{y}) u {u} vs {eu}"
            );
            assert!(
                (f64::from(v) - ev).abs() < 1e-3,
                "{grid:?} ({x},{y}) v {v} vs {ev}"
            );
            assert!((f64::from(out.depth_m[i]) - z).abs() < 1e-5);
        }
        // The silhouette is the one of the drawn frame: wider at t (closer).
        let (b, _) = bbox(&out, &out.coverage);
        let expect_x_min = (159.5 - 300.0 * 0.2 / (z - 0.0)).ceil() as usize;
        assert_eq!(b.0, expect_x_min, "{grid:?}");
    }
}

#[test]
fn link_motion_gives_the_exact_flow_against_ray_casting() {
    // A tilted box (two faces visible) moving and turning between t-1 and t, seen by a
    // camera that also moves. Expected flow from an independent ray-box intersection.
    let k = k320();
    let half = [0.15f64, 0.1, 0.08];
    let mut r = renderer(
        RenderConfig::default(),
        &[box_mesh(1, half.map(|h| h as f32))],
    );
    let rot = |ax: f64, ay: f64| UnitQuaternion::from_euler_angles(ax, ay, 0.0);
    let prev_links = [
        Isometry3::identity(),
        Isometry3::from_parts(Translation3::new(0.02, -0.01, 1.0), rot(0.3, 0.5)),
    ];
    let cur_links = [
        Isometry3::identity(),
        Isometry3::from_parts(Translation3::new(0.05, 0.01, 0.97), rot(0.33, 0.45)),
    ];
    let cam_prev = at(0.0, 0.0, 0.0);
    let cam_cur = Isometry3::from_parts(
        Translation3::new(0.01, 0.0, 0.02),
        UnitQuaternion::from_euler_angles(0.0, 0.02, 0.01),
    );
    let prev = RobotView {
        camera_from_base: cam_prev,
        base_from_link: &prev_links,
    };
    let cur = RobotView {
        camera_from_base: cam_cur,
        base_from_link: &cur_links,
    };
    let out = render(&mut r, &k, cur, Some(prev));
    let px = interior(&out);
    assert!(px.len() > 3000, "{}", px.len());
    let mut max_err = 0.0f64;
    for &(x, y) in &px {
        let pixel = Point2::new(x as f64, y as f64);
        let cam_from_box_t = cam_cur * cur_links[1];
        let p_box = ray_box(&k, pixel, &cam_from_box_t, half).unwrap();
        let depth = (cam_from_box_t * p_box).z;
        let p_prev = k.project(&(cam_prev * prev_links[1] * p_box)).unwrap();
        let (u, v) = out.flow.get(x, y);
        let err = (f64::from(u) - (x as f64 - p_prev.x))
            .abs()
            .max((f64::from(v) - (y as f64 - p_prev.y)).abs());
        max_err = max_err.max(err);
        let dz = (f64::from(out.depth_m[y * 320 + x]) - depth).abs();
        assert!(
            dz < 2e-5,
            "({x},{y}) depth {} vs {depth}",
            out.depth_m[y * 320 + x]
        );
    }
    assert!(max_err < 1e-3, "max flow error {max_err} px");
    // The motion is not trivial: several pixels of flow.
    let (u, _) = out.flow.get(px[px.len() / 2].0, px[px.len() / 2].1);
    assert!(u.abs() > 2.0, "{u}");
}

#[test]
fn exact_flow_agrees_with_tvl1_of_the_shaded_renders() {
    // A turned box moving ~3 px right and ~1.5 px down at 160x120: the paper's variant
    // (TV-L1 between shaded renders) and the exact flow have close medians.
    let k = Intrinsics::new(160, 120, 150.0, 150.0, 79.5, 59.5).unwrap();
    let mut r = renderer(RenderConfig::default(), &[box_mesh(0, [0.15, 0.12, 0.1])]);
    let turn = UnitQuaternion::from_euler_angles(0.5, 0.6, 0.1);
    let prev_links = [Isometry3::from_parts(
        Translation3::new(0.0, 0.0, 1.0),
        turn,
    )];
    let cur_links = [Isometry3::from_parts(
        Translation3::new(0.02, 0.01, 1.0),
        turn,
    )];
    let prev = RobotView {
        camera_from_base: Isometry3::identity(),
        base_from_link: &prev_links,
    };
    let cur = RobotView {
        camera_from_base: Isometry3::identity(),
        base_from_link: &cur_links,
    };
    let exact = render(&mut r, &k, cur, Some(prev));
    let mut scratch = RenderOutput::default();
    let mut out = RenderOutput::default();
    let tv = tvl1_body_flow(
        &mut r,
        &k,
        prev,
        cur,
        &FlowParams::default(),
        &mut scratch,
        &mut out,
    )
    .unwrap();
    // Gray images: white background, darker robot.
    let gray = out.gray.as_ref().unwrap();
    assert_eq!(gray.get(0, 0), 255.0);
    assert!(gray.get(80, 60) < 220.0);
    assert_eq!(out.coverage, exact.coverage);
    // Exact: 150 * 0.02 / z and 150 * 0.01 / z over the box (z about 0.85..1.1).
    let e = crate::body_motion_error(&exact.flow, &tv, &scratch.coverage).unwrap();
    let exact_med = crate::body_motion_error(&exact.flow, &exact.flow, &exact.coverage)
        .unwrap()
        .expected_median_px;
    assert!(
        (exact_med[0] - 3.0).abs() < 0.6 && (exact_med[1] - 1.5).abs() < 0.3,
        "{exact_med:?}"
    );
    let tv_med = e.observed_median_px;
    assert!(
        (tv_med[0] - exact_med[0]).abs() < 0.3 && (tv_med[1] - exact_med[1]).abs() < 0.3,
        "TV-L1 {tv_med:?} vs exact {exact_med:?}"
    );
}
