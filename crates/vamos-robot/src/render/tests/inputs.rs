//! Bad input as typed errors; the synthetic arm and its simplified meshes.

use super::*;

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
