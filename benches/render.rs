//! Body rendering timing: render + exact body flow + mask (CPU back-end, one thread) of a
//! synthetic 7-joint arm of ~100k triangles about 1 m from the camera, at three sizes; and
//! the same arm at 20k triangles (what a render-time decimation would leave). Then the
//! committed Franka Panda (`tests/fixtures/robot/franka_panda`) on the CPU back-end and,
//! with `--features wgpu`, on the wgpu back-end (whatever adapter wgpu picks: Mesa
//! lavapipe on a machine without a GPU).

// criterion_group! generates undocumented items.
#![allow(missing_docs)]

use std::time::Duration;

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use nalgebra::{Isometry3, Point3, Vector3};
use vamos::robot::render::shapes::SyntheticArm;
use vamos::robot::render::{
    BodyRenderer, CpuRenderer, RenderConfig, RenderFrame, RenderOutput, RobotView,
};
use vamos::robot::{Intrinsics, Robot, RobotConfig};

fn bench_render(c: &mut Criterion) {
    let mut group = c.benchmark_group("render");
    group.sample_size(20);
    group.warm_up_time(Duration::from_millis(500));
    group.measurement_time(Duration::from_secs(3));
    for triangles in [100_000usize, 20_000] {
        let arm = SyntheticArm::new(triangles);
        let q1 = SyntheticArm::POSE_RAD;
        let q0: Vec<f64> = q1.iter().map(|a| a - 0.02).collect();
        let prev_links = arm.base_from_link(&q0);
        let cur_links = arm.base_from_link(&q1);
        let camera_from_base = SyntheticArm::camera_from_base();
        for cull in [false, true] {
            let config = RenderConfig {
                cull_back_faces: cull,
                ..RenderConfig::default()
            };
            let Ok(mut renderer) = CpuRenderer::new(&config) else {
                continue;
            };
            if renderer.prepare(&arm.meshes).is_err() {
                continue;
            }
            for (w, h) in [(160u32, 120u32), (320, 240), (640, 480)] {
                let Ok(k) = SyntheticArm::intrinsics(w, h) else {
                    continue;
                };
                let frame = RenderFrame {
                    intrinsics: &k,
                    current: RobotView {
                        camera_from_base,
                        base_from_link: &cur_links,
                    },
                    previous: Some(RobotView {
                        camera_from_base,
                        base_from_link: &prev_links,
                    }),
                    shade: false,
                };
                let mut out = RenderOutput::default();
                if renderer.render(&frame, &mut out).is_err() {
                    continue;
                }
                eprintln!(
                    "{} triangles, {w}x{h}: {:.1} % of the image covered",
                    arm.triangle_count(),
                    100.0 * out.covered_pixels() as f64 / f64::from(w * h)
                );
                let name = format!(
                    "{}k{}",
                    arm.triangle_count() / 1000,
                    if cull { "/cull" } else { "" }
                );
                let id = BenchmarkId::new(name, format!("{w}x{h}"));
                group.bench_function(id, |bench| {
                    bench.iter(|| renderer.render(&frame, &mut out));
                });
            }
        }
    }
    group.finish();
}

/// `base_from_link` of every link.
type LinkPoses = Vec<Isometry3<f64>>;

/// The panda at a bent pose and the same pose 0.02 rad earlier on every joint.
fn panda_poses(robot: &Robot) -> Option<(LinkPoses, LinkPoses)> {
    let names: Vec<String> = robot.joints().iter().map(|j| j.name.clone()).collect();
    let pose = |delta: f64| -> Vec<f64> {
        names
            .iter()
            .map(|n| match n.as_str() {
                "panda_joint2" => -0.3 + delta,
                "panda_joint4" => -2.0 + delta,
                "panda_joint6" => 1.8 + delta,
                _ => delta,
            })
            .collect()
    };
    let mut mapper = robot.joint_mapper();
    let cur = robot
        .forward(&mapper.map(&names, &pose(0.0)).ok()?.positions)
        .ok()?;
    let prev = robot
        .forward(&mapper.map(&names, &pose(-0.02)).ok()?.positions)
        .ok()?;
    Some((cur, prev))
}

fn bench_panda(c: &mut Criterion) {
    let dir = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/fixtures/robot/franka_panda"
    );
    let Ok(robot) = Robot::load(dir.as_ref(), &RobotConfig::default()) else {
        eprintln!("cannot load {dir}");
        return;
    };
    let Some((cur, prev)) = panda_poses(&robot) else {
        return;
    };
    // 1.2 m in front of the arm, 0.5 m up, looking at its middle.
    let camera_from_base = Isometry3::face_towards(
        &Point3::new(1.2, 0.0, 0.5),
        &Point3::new(0.0, 0.0, 0.4),
        &Vector3::new(0.0, 0.0, -1.0),
    )
    .inverse();
    let config = RenderConfig::default();
    let mut renderers: Vec<Box<dyn BodyRenderer>> = Vec::new();
    if let Ok(r) = CpuRenderer::new(&config) {
        renderers.push(Box::new(r));
    }
    #[cfg(feature = "wgpu")]
    match vamos::robot::render::WgpuRenderer::new(&config) {
        Ok(r) => {
            eprintln!(
                "wgpu adapter: {} ({:?})",
                r.adapter_name(),
                r.adapter_type()
            );
            renderers.push(Box::new(r));
        }
        Err(e) => eprintln!("no wgpu back-end: {e}"),
    }
    let mut group = c.benchmark_group("render_panda");
    group.sample_size(20);
    group.warm_up_time(Duration::from_millis(500));
    group.measurement_time(Duration::from_secs(3));
    for renderer in &mut renderers {
        if renderer.prepare(robot.link_meshes()).is_err() {
            continue;
        }
        for (w, h) in [(160u32, 120u32), (320, 240), (640, 480)] {
            let Ok(k) = Intrinsics::from_fov(w, h, 70.0) else {
                continue;
            };
            let frame = RenderFrame {
                intrinsics: &k,
                current: RobotView {
                    camera_from_base,
                    base_from_link: &cur,
                },
                previous: Some(RobotView {
                    camera_from_base,
                    base_from_link: &prev,
                }),
                shade: false,
            };
            let mut out = RenderOutput::default();
            if renderer.render(&frame, &mut out).is_err() {
                continue;
            }
            let id = BenchmarkId::new(renderer.name(), format!("{w}x{h}"));
            group.bench_function(id, |bench| {
                bench.iter(|| renderer.render(&frame, &mut out));
            });
        }
    }
    group.finish();
}

criterion_group!(benches, bench_render, bench_panda);
criterion_main!(benches);
