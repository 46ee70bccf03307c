//! The wgpu back-end against the CPU reference (only with `--features wgpu`). These
//! tests need a wgpu adapter (on a machine without a GPU: Mesa lavapipe, Debian
//! `mesa-vulkan-drivers libvulkan1`). Without one they say so on stderr and pass, unless
//! `VAMOS_REQUIRE_GPU_TESTS=1` (set by CI, which installs lavapipe), where they FAIL.
//!
//! Observed on lavapipe (LLVM 15, x86-64): see the numbers printed by each test and
//! `benches/README.md`; the asserted tolerances are below.

// Clippy's allow-unwrap-in-tests does not see through `cfg(all(test, feature))`.
#![allow(clippy::unwrap_used)]

use super::shapes::{SyntheticArm, cuboid};
use super::*;
use crate::{Robot, RobotConfig};
use nalgebra::{Point3, Translation3, UnitQuaternion, Vector3};

/// Mask and coverage IoU must exceed this.
const MIN_IOU: f64 = 0.99;
/// Depth difference on pixels both back-ends cover with the same link, metres.
const DEPTH_TOL_M: f32 = 1e-3;
/// Flow difference on interior pixels (the pixel and its 8 neighbours covered by the same
/// link in both renders), pixels.
const FLOW_TOL_PX: f32 = 0.05;

/// True (after a notice on stderr) when no wgpu adapter exists and the GPU tests are not
/// required: the caller returns early.
fn skip_without_adapter(test: &str) -> bool {
    if std::env::var("VAMOS_REQUIRE_GPU_TESTS").is_ok_and(|v| v == "1")
        || gpu::default_adapter_type().is_some()
    {
        return false;
    }
    eprintln!(
        "{test}: SKIPPED, no wgpu adapter (install Mesa lavapipe: mesa-vulkan-drivers \
         libvulkan1; VAMOS_REQUIRE_GPU_TESTS=1 makes this a failure)"
    );
    true
}

fn gpu(config: &RenderConfig) -> WgpuRenderer {
    match WgpuRenderer::new(config) {
        Ok(r) => r,
        Err(e) => panic!("the wgpu back-end tests need a wgpu adapter: {e}"),
    }
}

#[derive(Debug)]
struct Agreement {
    coverage_iou: f64,
    mask_iou: f64,
    /// Fraction of pixels covered by both where the link ids differ.
    link_mismatch: f64,
    max_depth_diff_m: f32,
    interior: usize,
    max_flow_diff_px: f32,
    /// Interior pixels where exactly one of the two flows is NaN.
    flow_nan_mismatch: usize,
}

fn iou(a: &[bool], b: &[bool]) -> f64 {
    let inter = a.iter().zip(b).filter(|(x, y)| **x && **y).count();
    let union = a.iter().zip(b).filter(|(x, y)| **x || **y).count();
    if union == 0 {
        1.0
    } else {
        inter as f64 / union as f64
    }
}

fn compare(cpu: &RenderOutput, gpu: &RenderOutput) -> Agreement {
    assert_eq!((cpu.width, cpu.height), (gpu.width, gpu.height));
    let (w, h) = (cpu.width, cpu.height);
    let mut both = 0usize;
    let mut link_mismatch = 0usize;
    let mut max_depth = 0.0f32;
    let mut interior = 0usize;
    let mut max_flow = 0.0f32;
    let mut nan_mismatch = 0usize;
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            if !(cpu.coverage[i] && gpu.coverage[i]) {
                continue;
            }
            both += 1;
            if cpu.link[i] != gpu.link[i] {
                link_mismatch += 1;
                continue;
            }
            max_depth = max_depth.max((cpu.depth_m[i] - gpu.depth_m[i]).abs());
            let inside = x > 0 && y > 0 && x + 1 < w && y + 1 < h && {
                let l = cpu.link[i];
                (y - 1..=y + 1).all(|yy| {
                    (x - 1..=x + 1).all(|xx| {
                        let j = yy * w + xx;
                        cpu.link[j] == l && gpu.link[j] == l
                    })
                })
            };
            if !inside {
                continue;
            }
            interior += 1;
            let (cu, cv, gu, gv) = (cpu.flow.u[i], cpu.flow.v[i], gpu.flow.u[i], gpu.flow.v[i]);
            if cu.is_nan() != gu.is_nan() || cv.is_nan() != gv.is_nan() {
                nan_mismatch += 1;
            } else if !cu.is_nan() {
                max_flow = max_flow.max((cu - gu).abs()).max((cv - gv).abs());
            }
        }
    }
    Agreement {
        coverage_iou: iou(&cpu.coverage, &gpu.coverage),
        mask_iou: iou(&cpu.mask, &gpu.mask),
        link_mismatch: link_mismatch as f64 / both.max(1) as f64,
        max_depth_diff_m: max_depth,
        interior,
        max_flow_diff_px: max_flow,
        flow_nan_mismatch: nan_mismatch,
    }
}

fn assert_agree(a: &Agreement, what: &str) {
    eprintln!("{what}: {a:?}");
    assert!(a.coverage_iou > MIN_IOU, "{what}: {a:?}");
    assert!(a.mask_iou > MIN_IOU, "{what}: {a:?}");
    assert!(a.link_mismatch < 0.01, "{what}: {a:?}");
    assert!(a.max_depth_diff_m < DEPTH_TOL_M, "{what}: {a:?}");
    assert!(a.interior > 100, "{what}: {a:?}");
    assert!(a.max_flow_diff_px < FLOW_TOL_PX, "{what}: {a:?}");
    assert_eq!(a.flow_nan_mismatch, 0, "{what}: {a:?}");
}

fn both(
    config: &RenderConfig,
    meshes: &[LinkMesh],
    frame: &RenderFrame<'_>,
) -> (RenderOutput, RenderOutput) {
    let mut c = CpuRenderer::new(config).unwrap();
    c.prepare(meshes).unwrap();
    let mut g = gpu(config);
    g.prepare(meshes).unwrap();
    let (mut co, mut go) = (RenderOutput::default(), RenderOutput::default());
    c.render(frame, &mut co).unwrap();
    g.render(frame, &mut go).unwrap();
    (co, go)
}

/// The synthetic arm at its pose (t) and 0.03 rad earlier on every joint (t-1).
fn arm_poses(arm: &SyntheticArm) -> (Vec<Isometry3<f64>>, Vec<Isometry3<f64>>) {
    let q1 = SyntheticArm::POSE_RAD;
    let q0: Vec<f64> = q1.iter().map(|a| a - 0.03).collect();
    (arm.base_from_link(&q1), arm.base_from_link(&q0))
}

/// A frame with flow from `prev` to `cur`, both seen from the same camera, no gray image.
fn moving_frame<'a>(
    k: &'a Intrinsics,
    cam: Isometry3<f64>,
    cur: &'a [Isometry3<f64>],
    prev: &'a [Isometry3<f64>],
) -> RenderFrame<'a> {
    RenderFrame {
        intrinsics: k,
        current: RobotView {
            camera_from_base: cam,
            base_from_link: cur,
        },
        previous: Some(RobotView {
            camera_from_base: cam,
            base_from_link: prev,
        }),
        shade: false,
    }
}

#[test]
fn synthetic_arm_agrees_with_the_cpu_on_both_grids_and_with_culling() {
    if skip_without_adapter("synthetic_arm_agrees_with_the_cpu_on_both_grids_and_with_culling") {
        return;
    }
    let arm = SyntheticArm::new(20_000);
    let (cur, prev) = arm_poses(&arm);
    let cam1 = SyntheticArm::camera_from_base();
    // The camera moves too (1 cm sideways, a small turn).
    let cam0 = Isometry3::from_parts(
        Translation3::new(0.01, 0.0, 0.0),
        UnitQuaternion::from_euler_angles(0.0, 0.01, 0.0),
    ) * cam1;
    for (w, h) in [(160u32, 120u32), (320, 240)] {
        let k = SyntheticArm::intrinsics(w, h).unwrap();
        let frame = RenderFrame {
            intrinsics: &k,
            current: RobotView {
                camera_from_base: cam1,
                base_from_link: &cur,
            },
            previous: Some(RobotView {
                camera_from_base: cam0,
                base_from_link: &prev,
            }),
            shade: false,
        };
        for grid in [FlowGrid::Target, FlowGrid::Source] {
            for cull in [false, true] {
                let config = RenderConfig {
                    flow_grid: grid,
                    cull_back_faces: cull,
                    ..RenderConfig::default()
                };
                let (c, g) = both(&config, &arm.meshes, &frame);
                assert!(c.covered_pixels() as f64 > 0.1 * f64::from(w * h));
                assert_agree(
                    &compare(&c, &g),
                    &format!("arm {w}x{h} {grid:?} cull {cull}"),
                );
            }
        }
    }
}

#[test]
fn box_scene_agrees_and_flow_matches_a_hand_computed_value() {
    if skip_without_adapter("box_scene_agrees_and_flow_matches_a_hand_computed_value") {
        return;
    }
    // A 0.2 m box 1 m ahead; at t-1 it sat 2 cm further left (camera x): a pure image
    // translation of fx * 0.02 / z at the front face (z = 0.9 m).
    let meshes = [LinkMesh {
        link: 0,
        mesh: cuboid([0.1, 0.1, 0.1]),
    }];
    let k = Intrinsics::new(320, 240, 300.0, 300.0, 159.5, 119.5).unwrap();
    let cur = [Isometry3::translation(0.0, 0.0, 1.0)];
    let prev = [Isometry3::translation(-0.02, 0.0, 1.0)];
    let frame = RenderFrame {
        intrinsics: &k,
        current: RobotView {
            camera_from_base: Isometry3::identity(),
            base_from_link: &cur,
        },
        previous: Some(RobotView {
            camera_from_base: Isometry3::identity(),
            base_from_link: &prev,
        }),
        shade: false,
    };
    let (c, g) = both(&RenderConfig::default(), &meshes, &frame);
    assert_agree(&compare(&c, &g), "box");
    // Centre pixel: depth 0.9 m, flow (300 * 0.02 / 0.9, 0).
    let i = 119 * 320 + 159;
    assert!((g.depth_m[i] - 0.9).abs() < 1e-5, "{}", g.depth_m[i]);
    let expected = 300.0 * 0.02 / 0.9;
    assert!((g.flow.u[i] - expected).abs() < 1e-3, "{}", g.flow.u[i]);
    assert!(g.flow.v[i].abs() < 1e-3, "{}", g.flow.v[i]);
    // The front face spans x in [-0.1, 0.1] m at z = 0.9: +-33.3 px around 159.5.
    let row = &g.coverage[119 * 320..120 * 320];
    let first = row.iter().position(|&c| c).unwrap();
    let last = row.iter().rposition(|&c| c).unwrap();
    assert_eq!((first, last), (127, 192));
    // Off the robot: +inf depth, NaN flow, NO_LINK.
    assert!(g.depth_m[0].is_infinite() && g.flow.u[0].is_nan() && g.link[0] == NO_LINK);
}

fn panda() -> (Robot, Vec<Isometry3<f64>>, Vec<Isometry3<f64>>) {
    let dir = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../tests/fixtures/robot/franka_panda"
    );
    let robot = Robot::load(dir.as_ref(), &RobotConfig::default()).unwrap();
    let names: Vec<String> = robot.joints().iter().map(|j| j.name.clone()).collect();
    let pose = |delta: f64| -> Vec<f64> {
        names
            .iter()
            .map(|n| match n.as_str() {
                "panda_joint1" => 0.3 + delta,
                "panda_joint2" => -0.3 + delta,
                "panda_joint4" => -2.0 - delta,
                "panda_joint6" => 1.8 + delta,
                _ => 0.0,
            })
            .collect()
    };
    let mut mapper = robot.joint_mapper();
    let cur = robot
        .forward(&mapper.map(&names, &pose(0.0)).unwrap().positions)
        .unwrap();
    let prev = robot
        .forward(&mapper.map(&names, &pose(-0.02)).unwrap().positions)
        .unwrap();
    (robot, cur, prev)
}

/// A camera 1.2 m in front of the panda, 0.5 m up, looking at its middle.
fn panda_camera() -> Isometry3<f64> {
    let eye = Point3::new(1.2, 0.0, 0.5);
    let target = Point3::new(0.0, 0.0, 0.4);
    Isometry3::face_towards(&eye, &target, &Vector3::new(0.0, 0.0, -1.0)).inverse()
}

#[test]
fn franka_panda_agrees_with_the_cpu() {
    if skip_without_adapter("franka_panda_agrees_with_the_cpu") {
        return;
    }
    let (robot, cur, prev) = panda();
    let cam = panda_camera();
    for (w, h) in [(160u32, 120u32), (320, 240), (640, 480)] {
        let k = Intrinsics::from_fov(w, h, 70.0).unwrap();
        let frame = moving_frame(&k, cam, &cur, &prev);
        for grid in [FlowGrid::Target, FlowGrid::Source] {
            let config = RenderConfig {
                flow_grid: grid,
                ..RenderConfig::default()
            };
            let (c, g) = both(&config, robot.link_meshes(), &frame);
            assert!(c.covered_pixels() as f64 > 0.05 * f64::from(w * h));
            assert_agree(&compare(&c, &g), &format!("panda {w}x{h} {grid:?}"));
        }
    }
}

#[test]
fn without_previous_view_flow_is_nan_and_shade_and_errors_work() {
    if skip_without_adapter("without_previous_view_flow_is_nan_and_shade_and_errors_work") {
        return;
    }
    let (robot, cur, _) = panda();
    let k = Intrinsics::from_fov(160, 120, 70.0).unwrap();
    let mut g = gpu(&RenderConfig::default());
    g.prepare(robot.link_meshes()).unwrap();
    let mut out = RenderOutput::default();
    let mut frame = RenderFrame {
        intrinsics: &k,
        current: RobotView {
            camera_from_base: panda_camera(),
            base_from_link: &cur,
        },
        previous: None,
        shade: false,
    };
    g.render(&frame, &mut out).unwrap();
    assert!(out.covered_pixels() > 500);
    assert!(out.flow.u.iter().chain(&out.flow.v).all(|v| v.is_nan()));
    assert!(out.gray.is_none());
    // The mask is the coverage grown by 2 px: strictly larger, and contains it.
    assert!(out.mask_pixels() > out.covered_pixels());
    assert!(out.coverage.iter().zip(&out.mask).all(|(c, m)| !c || *m));
    // Shaded frames (drawn by the CPU path) carry a gray image.
    frame.shade = true;
    g.render(&frame, &mut out).unwrap();
    let gray = out.gray.as_ref().unwrap();
    assert_eq!(gray.data()[0], 255.0);
    // Too few link poses: a typed error, and the renderer still works afterwards.
    frame.shade = false;
    let short = &cur[..2];
    let bad = RenderFrame {
        current: RobotView {
            camera_from_base: panda_camera(),
            base_from_link: short,
        },
        ..frame
    };
    assert!(matches!(
        g.render(&bad, &mut out),
        Err(RenderError::LinkOutOfRange { .. })
    ));
    g.render(&frame, &mut out).unwrap();
    assert!(out.covered_pixels() > 500);
}

#[test]
fn create_renderer_builds_the_requested_back_end() {
    if skip_without_adapter("create_renderer_builds_the_requested_back_end") {
        return;
    }
    let wgpu_config = RenderConfig {
        backend: RenderBackend::Wgpu,
        ..RenderConfig::default()
    };
    match create_renderer(&wgpu_config) {
        Ok(r) => assert_eq!(r.name(), "wgpu"),
        Err(e) => panic!("backend = wgpu needs a wgpu adapter (e.g. Mesa lavapipe): {e}"),
    }
    // auto: the GPU only on hardware adapters; a software one (lavapipe) keeps the CPU.
    let auto = create_renderer(&RenderConfig::default()).unwrap();
    let expected = match gpu::default_adapter_type() {
        Some(wgpu::DeviceType::DiscreteGpu | wgpu::DeviceType::IntegratedGpu) => "wgpu",
        _ => "cpu",
    };
    assert_eq!(auto.name(), expected);
}

#[test]
fn auto_times_both_back_ends_then_keeps_the_faster() {
    use super::auto::{AutoRenderer, Choice, PROBE_FRAMES, decide};
    // The decision rule: warm-up frames ignored, lower minimum wins, ties keep the CPU.
    assert_eq!(decide(&[9.0, 1.0, 1.0, 1.0], &[0.1, 2.0, 2.0]), None);
    assert_eq!(
        decide(&[9.0, 1.0, 3.0, 1.0], &[0.1, 2.0, 0.5, 2.0]),
        Some(Choice::Wgpu)
    );
    assert_eq!(
        decide(&[0.1, 1.0, 1.0, 1.0], &[0.0, 1.0, 1.0, 1.0]),
        Some(Choice::Cpu)
    );
    if skip_without_adapter("auto_times_both_back_ends_then_keeps_the_faster") {
        return;
    }
    let arm = SyntheticArm::new(20_000);
    let (cur, prev) = arm_poses(&arm);
    let k = SyntheticArm::intrinsics(320, 240).unwrap();
    let frame = moving_frame(&k, SyntheticArm::camera_from_base(), &cur, &prev);
    let config = RenderConfig::default();
    let mut reference = CpuRenderer::new(&config).unwrap();
    reference.prepare(&arm.meshes).unwrap();
    let mut want = RenderOutput::default();
    reference.render(&frame, &mut want).unwrap();

    let mut auto = AutoRenderer::new(CpuRenderer::new(&config).unwrap(), Some(gpu(&config)));
    auto.prepare(&arm.meshes).unwrap();
    assert_eq!(auto.name(), "auto");
    let probe = 2 * (PROBE_FRAMES + 1);
    let mut out = RenderOutput::default();
    for i in 0..probe + 2 {
        auto.render(&frame, &mut out).unwrap();
        // Probe frames come from either back-end: each agrees with the CPU reference.
        assert_agree(&compare(&want, &out), &format!("auto frame {i}"));
        let (c, g) = auto.probe_times();
        if i + 1 < probe {
            assert_eq!(auto.choice(), None, "frame {i}");
            // Alternating: the CPU draws first, then the GPU, and so on.
            assert_eq!((c.len(), g.len()), (i / 2 + 1, i.div_ceil(2)));
        }
    }
    let (c, g) = auto.probe_times();
    eprintln!(
        "auto probe: cpu {c:?} s, wgpu {g:?} s -> {:?}",
        auto.choice()
    );
    assert_eq!((c.len(), g.len()), (PROBE_FRAMES + 1, PROBE_FRAMES + 1));
    let choice = auto.choice().unwrap();
    assert_eq!(choice, decide(c, g).unwrap());
    assert_eq!(
        auto.name(),
        if choice == Choice::Cpu { "cpu" } else { "wgpu" }
    );
    // On a software adapter (lavapipe) the CPU rasteriser is several times faster.
    if gpu::default_adapter_type() == Some(wgpu::DeviceType::Cpu) {
        assert_eq!(choice, Choice::Cpu);
    }
}
