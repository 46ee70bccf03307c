//! Rasterisation: rectangles and depth, occlusion, near-plane clipping, culling, the top-left rule.

use super::*;

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
