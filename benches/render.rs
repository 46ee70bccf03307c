//! Body rendering timing: render + exact body flow + mask (CPU back-end, one thread) of a
//! synthetic 7-joint arm of ~100k triangles about 1 m from the camera, at three sizes; and
//! the same arm at 20k triangles (what a render-time decimation would leave).

// criterion_group! generates undocumented items.
#![allow(missing_docs)]

use std::time::Duration;

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use vamos::robot::render::shapes::SyntheticArm;
use vamos::robot::render::{
    BodyRenderer, CpuRenderer, RenderConfig, RenderFrame, RenderOutput, RobotView,
};

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

criterion_group!(benches, bench_render);
criterion_main!(benches);
