//! Thread-CPU timing of the CPU body renderer on the synthetic arm (not part of the API):
//! render + exact body flow + mask, min over repetitions. Thread CPU time does not count
//! waiting for a core, so it is meaningful on a loaded machine.
//!
//! `cargo run --release --example render_time -- [triangles] [reps] [cull|nocull] [simplify_cell_m]`

use vamos::robot::render::shapes::SyntheticArm;
use vamos::robot::render::{
    BodyRenderer, CpuRenderer, RenderConfig, RenderFrame, RenderOutput, RobotView,
};

/// CPU time of the calling thread, ms.
fn thread_cpu_ms() -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec; the clock id is a constant.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    if rc != 0 {
        return f64::NAN;
    }
    ts.tv_sec as f64 * 1e3 + ts.tv_nsec as f64 * 1e-6
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let triangles: usize = args.get(1).map_or(Ok(100_000), |s| s.parse())?;
    let reps: usize = args.get(2).map_or(Ok(50), |s| s.parse())?;
    let cull = args.get(3).is_some_and(|s| s == "cull");
    let simplify_cell_m: f64 = args.get(4).map_or(Ok(0.0), |s| s.parse())?;
    let arm = SyntheticArm::new(triangles);
    let q1 = SyntheticArm::POSE_RAD;
    let q0: Vec<f64> = q1.iter().map(|a| a - 0.02).collect();
    let prev_links = arm.base_from_link(&q0);
    let cur_links = arm.base_from_link(&q1);
    let camera_from_base = SyntheticArm::camera_from_base();
    let config = RenderConfig {
        cull_back_faces: cull,
        simplify_cell_m,
        ..RenderConfig::default()
    };
    let mut renderer = CpuRenderer::new(&config)?;
    let t0 = thread_cpu_ms();
    renderer.prepare(&arm.meshes)?;
    let prepare_ms = thread_cpu_ms() - t0;
    println!(
        "{} triangles ({} drawn; cull {cull}, simplify {simplify_cell_m} m), prepare {prepare_ms:.2} ms",
        arm.triangle_count(),
        renderer.triangle_count()
    );
    for (w, h) in [(160u32, 120u32), (320, 240), (640, 480)] {
        let k = SyntheticArm::intrinsics(w, h)?;
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
        let mut best = f64::INFINITY;
        for _ in 0..reps {
            let t = thread_cpu_ms();
            renderer.render(&frame, &mut out)?;
            best = best.min(thread_cpu_ms() - t);
        }
        println!(
            "{w}x{h}: {best:.3} ms (min of {reps}), {:.1} % covered",
            100.0 * out.covered_pixels() as f64 / f64::from(w * h)
        );
    }
    Ok(())
}
