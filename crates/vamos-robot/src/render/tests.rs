//! Tests of the render module against analytic expectations (boxes at known poses, rays
//! intersected with boxes independently of the rasteriser).

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

#[test]
fn box_renders_to_the_expected_rectangle_and_depth() {
    // Box 0.4 x 0.2 x 0.1 m centred 1 m ahead: its front face (z = 0.95) is the
    // silhouette, x in 159.5 +- 300 * 0.2 / 0.95 = [96.34, 222.66], y in
    // 119.5 +- 300 * 0.1 / 0.95 = [87.92, 151.08]: pixel centres 97..=222, 88..=151.
    let k = k320();
    let mut r = renderer(RenderConfig::default(), &[box_mesh(0, [0.2, 0.1, 0.05])]);
    let poses = [Isometry3::identity()];
    let view = RobotView {
        camera_from_base: at(0.0, 0.0, 1.0),
        base_from_link: &poses,
    };
    let out = render(&mut r, &k, view, None);
    let (b, n) = bbox(&out, &out.coverage);
    assert_eq!(b, (97, 222, 88, 151));
    assert_eq!(n, 126 * 64, "the rectangle is full");
    let centre = 120 * 320 + 160;
    assert!(
        (out.depth_m[centre] - 0.95).abs() < 1e-6,
        "{}",
        out.depth_m[centre]
    );
    assert!(out.depth_m[0].is_infinite() && out.depth_m[0] > 0.0);
    assert_eq!(out.link[centre], 0);
    assert_eq!(out.link[0], NO_LINK);
    // No previous view: no flow.
    assert!(out.flow.u.iter().all(|u| u.is_nan()));
    // Mask margin 2 (a disc): two columns left of the edge, not three; diagonal corners
    // at distance sqrt(2) in, sqrt(8) out.
    let m = |x: usize, y: usize| out.mask[y * 320 + x];
    assert!(m(95, 120) && !m(94, 120) && m(224, 120) && !m(225, 120));
    assert!(m(120, 86) && !m(120, 85) && m(120, 153) && !m(120, 154));
    assert!(m(96, 87) && !m(95, 86));
    // Exact count: rectangle + 2 px bands + quarter discs of radius 2 (3 px each corner
    // beyond the bands: (1,1), (1,2)... -> the disc of radius 2 has 13 px, its corner
    // quadrant outside the axes holds (1,1) only).
    let rect = 126 * 64;
    let bands = 2 * (126 + 64) * 2;
    assert_eq!(out.mask_pixels(), rect + bands + 4);
}

#[test]
fn nearer_box_occludes_the_farther_one() {
    let k = k320();
    let meshes = [
        box_mesh(0, [0.2, 0.2, 0.05]),
        box_mesh(1, [0.05, 0.05, 0.05]),
    ];
    let mut r = renderer(RenderConfig::default(), &meshes);
    // Link 1 drawn second but nearer (z 0.6): it must win. Then swap the depths.
    for (z0, z1) in [(1.0, 0.6), (0.6, 1.4)] {
        let poses = [at(0.0, 0.0, z0), at(0.0, 0.0, z1)];
        let view = RobotView {
            camera_from_base: Isometry3::identity(),
            base_from_link: &poses,
        };
        let out = render(&mut r, &k, view, None);
        let centre = 120 * 320 + 160;
        let (near_link, near_z) = if z1 < z0 { (1, z1) } else { (0, z0) };
        assert_eq!(out.link[centre], near_link);
        assert!((f64::from(out.depth_m[centre]) - (near_z - 0.05)).abs() < 1e-6);
        // A pixel only the big box covers.
        let side = 120 * 320 + 160 + 40;
        assert_eq!(out.link[side], 0);
    }
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
fn triangles_crossing_the_near_plane_are_clipped_not_dropped() {
    // A bar along the optical axis from z = -1 to z = 2, 0.1 m to the right: each of its
    // long triangles crosses the near plane, so only clipping draws it.
    let k = k320();
    let mut r = renderer(RenderConfig::default(), &[box_mesh(0, [0.02, 0.02, 1.5])]);
    let poses = [at(0.1, 0.0, 0.5)];
    let view = RobotView {
        camera_from_base: Isometry3::identity(),
        base_from_link: &poses,
    };
    let out = render(&mut r, &k, view, None);
    assert!(out.covered_pixels() > 1000, "{}", out.covered_pixels());
    let min_depth = out.depth_m.iter().copied().fold(f32::INFINITY, f32::min);
    assert!(min_depth >= 0.05 - 1e-6, "{min_depth}");
    // The bar reaches the right image border (its near end projects far right).
    assert!(out.coverage[119 * 320 + 319]);
    // Depth on the bar's left face (x = 0.08) along row 119 matches the ray intersection.
    let half = [0.02, 0.02, 1.5];
    for x in [200usize, 250, 300] {
        let p = ray_box(&k, Point2::new(x as f64, 119.0), &poses[0], half).unwrap();
        let z = (poses[0] * p).z;
        assert!((f64::from(out.depth_m[119 * 320 + x]) - z).abs() < 1e-4 * z);
    }
}

#[test]
fn back_face_culling_keeps_closed_convex_meshes_whole() {
    let k = k320();
    let meshes = [box_mesh(0, [0.2, 0.1, 0.05])];
    let links = [Isometry3::from_parts(
        Translation3::new(0.0, 0.0, 1.0),
        UnitQuaternion::from_euler_angles(0.4, 0.3, 0.2),
    )];
    let view = RobotView {
        camera_from_base: Isometry3::identity(),
        base_from_link: &links,
    };
    let plain = render(
        &mut renderer(RenderConfig::default(), &meshes),
        &k,
        view,
        None,
    );
    let culled_config = RenderConfig {
        cull_back_faces: true,
        ..RenderConfig::default()
    };
    let culled = render(
        &mut renderer(culled_config.clone(), &meshes),
        &k,
        view,
        None,
    );
    assert_eq!(plain.coverage, culled.coverage);
    assert_eq!(plain.depth_m, culled.depth_m);
    // Turned inside out (all triangles reversed), the near faces become back faces: with
    // culling only the far faces are drawn (same silhouette, larger depth); without, the
    // depth is unchanged.
    let mut inside_out = meshes[0].clone();
    inside_out
        .mesh
        .triangles
        .iter_mut()
        .for_each(|t| t.swap(1, 2));
    let inside_out = [inside_out];
    let far = render(&mut renderer(culled_config, &inside_out), &k, view, None);
    assert_eq!(far.coverage, plain.coverage);
    let centre = 120 * 320 + 160;
    assert!(far.depth_m[centre] > plain.depth_m[centre] + 0.05);
    let unculled = render(
        &mut renderer(RenderConfig::default(), &inside_out),
        &k,
        view,
        None,
    );
    assert_eq!(unculled.depth_m, plain.depth_m);
}

#[test]
fn top_left_rule_draws_a_shared_edge_once() {
    // A square with corners on pixel centres 10..20, split along its diagonal (pixel
    // centres lie on the shared edge): each centre belongs to exactly one triangle, and
    // the square covers 10 x 10 centres (left and top edges in, right and bottom out).
    let (w, h) = (32usize, 32usize);
    let quad = [
        [10.0f32, 10.0, 1.0],
        [20.0, 10.0, 1.0],
        [20.0, 20.0, 1.0],
        [10.0, 20.0, 1.0],
    ];
    let mut counts = vec![0u32; w * h];
    for tri in [[quad[0], quad[1], quad[2]], [quad[0], quad[2], quad[3]]] {
        let mut inv_z = vec![0.0f32; w * h];
        let mut ids = vec![u32::MAX; w * h];
        let mut t = cpu::tests_support::target(&mut inv_z, &mut ids, w, h);
        t.raster(tri, 0);
        for (c, id) in counts.iter_mut().zip(&ids) {
            *c += u32::from(*id == 0);
        }
    }
    assert!(counts.iter().all(|&c| c <= 1), "a pixel drawn twice");
    assert_eq!(counts.iter().sum::<u32>(), 100);
    assert_eq!(counts[10 * w + 10], 1);
    assert_eq!(counts[20 * w + 15], 0);
    assert_eq!(counts[15 * w + 20], 0);
}

#[test]
fn bad_input_is_a_typed_error() {
    let good = box_mesh(0, [0.1, 0.1, 0.1]);
    let mut r = CpuRenderer::new(&RenderConfig::default()).unwrap();
    // Out-of-range index.
    let mut bad = good.clone();
    bad.mesh.triangles.push([0, 1, 8]);
    assert!(matches!(
        r.prepare(&[good.clone(), bad]),
        Err(RenderError::IndexOutOfRange {
            mesh: 1,
            triangle: 12,
            index: 8,
            vertex_count: 8,
            ..
        })
    ));
    // NaN vertex.
    let mut bad = good.clone();
    bad.mesh.positions[3].y = f32::NAN;
    assert!(matches!(
        r.prepare(&[bad]),
        Err(RenderError::NonFiniteVertex {
            mesh: 0,
            vertex: 3,
            ..
        })
    ));
    // A link without a pose.
    r.prepare(&[good.clone(), box_mesh(3, [0.1, 0.1, 0.1])])
        .unwrap();
    let k = k320();
    let poses = [Isometry3::identity(); 2];
    let mut out = RenderOutput::default();
    let view = RobotView {
        camera_from_base: at(0.0, 0.0, 1.0),
        base_from_link: &poses,
    };
    let frame = RenderFrame {
        intrinsics: &k,
        current: view,
        previous: None,
        shade: false,
    };
    assert!(matches!(
        r.render(&frame, &mut out),
        Err(RenderError::LinkOutOfRange {
            link: 3,
            link_count: 2,
            which: "current"
        })
    ));
    r.prepare(std::slice::from_ref(&good)).unwrap();
    // Previous view with too few links.
    let frame2 = RenderFrame {
        previous: Some(RobotView {
            camera_from_base: Isometry3::identity(),
            base_from_link: &[],
        }),
        ..frame
    };
    assert!(matches!(
        r.render(&frame2, &mut out),
        Err(RenderError::LinkOutOfRange {
            which: "previous",
            ..
        })
    ));
    // NaN pose.
    let mut nan_poses = poses;
    nan_poses[1].translation.vector.x = f64::NAN;
    let frame3 = RenderFrame {
        current: RobotView {
            camera_from_base: at(0.0, 0.0, 1.0),
            base_from_link: &nan_poses,
        },
        ..frame
    };
    match r.render(&frame3, &mut out) {
        Err(RenderError::NonFinitePose { which, pose }) => {
            assert_eq!((which, pose.as_str()), ("current", "base_from_link[1]"));
        }
        other => panic!("{other:?}"),
    }
    // Zero-size image.
    let empty = Intrinsics { width: 0, ..k };
    let frame4 = RenderFrame {
        intrinsics: &empty,
        ..frame
    };
    assert!(matches!(
        r.render(&frame4, &mut out),
        Err(RenderError::Intrinsics(_))
    ));
    // Settings.
    let bad_near = RenderConfig {
        near_m: 0.0,
        ..RenderConfig::default()
    };
    assert!(matches!(
        CpuRenderer::new(&bad_near),
        Err(RenderError::BadConfig { name: "near_m", .. })
    ));
    // Without the feature the wgpu back-end is a typed error (gpu_tests.rs covers it).
    #[cfg(not(feature = "wgpu"))]
    {
        let gpu = RenderConfig {
            backend: RenderBackend::Wgpu,
            ..RenderConfig::default()
        };
        assert!(matches!(
            create_renderer(&gpu),
            Err(RenderError::BackendUnavailable {
                backend: RenderBackend::Wgpu,
                ..
            })
        ));
    }
    // The renderer still works after the errors.
    r.render(&frame, &mut out).unwrap();
    assert!(out.covered_pixels() > 0);
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

#[test]
fn synthetic_arm_covers_a_fifth_to_a_third_of_the_image() {
    let arm = SyntheticArm::new(20_000);
    let mut r = renderer(RenderConfig::default(), &arm.meshes);
    let k = SyntheticArm::intrinsics(320, 240).unwrap();
    let links = arm.base_from_link(&SyntheticArm::POSE_RAD);
    let view = RobotView {
        camera_from_base: SyntheticArm::camera_from_base(),
        base_from_link: &links,
    };
    let out = render(&mut r, &k, view, None);
    let fraction = out.covered_pixels() as f64 / (320.0 * 240.0);
    assert!((0.15..0.35).contains(&fraction), "{fraction}");
}

#[test]
fn simplified_arm_renders_almost_the_same_mask() {
    // 100k triangles (edges ~5 mm) clustered on an 8 mm grid (~2.7 px at 1 m, fx = 343 px).
    let arm = SyntheticArm::new(100_000);
    let k = SyntheticArm::intrinsics(320, 240).unwrap();
    let links = arm.base_from_link(&SyntheticArm::POSE_RAD);
    let view = RobotView {
        camera_from_base: SyntheticArm::camera_from_base(),
        base_from_link: &links,
    };
    let full = render(
        &mut renderer(RenderConfig::default(), &arm.meshes),
        &k,
        view,
        None,
    );
    let config = RenderConfig {
        simplify_cell_m: 0.008,
        ..RenderConfig::default()
    };
    let mut r = renderer(config, &arm.meshes);
    assert!(
        r.triangle_count() * 2 < arm.triangle_count(),
        "{}",
        r.triangle_count()
    );
    let simple = render(&mut r, &k, view, None);
    let inter = full
        .coverage
        .iter()
        .zip(&simple.coverage)
        .filter(|(a, b)| **a && **b)
        .count();
    let union = full
        .coverage
        .iter()
        .zip(&simple.coverage)
        .filter(|(a, b)| **a || **b)
        .count();
    let iou = inter as f64 / union as f64;
    assert!(iou > 0.97, "IoU {iou}, {} triangles", r.triangle_count());
    eprintln!("IoU {iou}, {} triangles", r.triangle_count());
}
