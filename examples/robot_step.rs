//! Thread-CPU timing of the whole per-frame robot step on a real robot package (not part of
//! the API): joint names -> positions, forward kinematics, camera pose, then render + exact
//! body flow + mask with the CPU back-end; min over repetitions. Thread CPU time does not
//! count waiting for a core, so it is meaningful on a loaded machine.
//!
//! `cargo run --release --example robot_step -- [ROBOT] [reps] [cull|nocull] [simplify_cell_m]`
//! (ROBOT defaults to the committed franka_panda; the camera looks at it from 1.2 m, the
//! arm in a bent pose, joint 1 turning by 0.02 rad per frame.)

use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use vamos::robot::render::{
    BodyRenderer, CpuRenderer, RenderConfig, RenderFrame, RenderOutput, RobotView,
};
use vamos::robot::{CameraConvention, Intrinsics, Robot, RobotConfig};

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
    let default = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/fixtures/robot/franka_panda"
    );
    let path = args
        .get(1)
        .filter(|s| !s.is_empty())
        .map_or(default, String::as_str);
    let reps: usize = args.get(2).map_or(Ok(50), |s| s.parse())?;
    let cull = args.get(3).is_some_and(|s| s == "cull");
    let simplify_cell_m: f64 = args.get(4).map_or(Ok(0.0), |s| s.parse())?;
    let robot = Robot::load(path.as_ref(), &RobotConfig::default())?;
    let names: Vec<String> = robot.joints().iter().map(|j| j.name.clone()).collect();
    let mut pose = vec![0.0; names.len()];
    for (i, name) in names.iter().enumerate() {
        pose[i] = match name.as_str() {
            "panda_joint2" => -0.3,
            "panda_joint4" => -2.0,
            "panda_joint6" => 1.8,
            _ => 0.0,
        };
    }
    // A camera 1.2 m in front of the base (looking back along -x), 0.5 m up, pitched
    // down 0.2 rad: the arm fills roughly a quarter of the image.
    let root = robot.links()[robot.root()].clone();
    let mut mount = robot.camera(&root, CameraConvention::Body)?;
    mount.link_from_optical = Isometry3::from_parts(
        Translation3::new(1.2, 0.0, 0.5),
        UnitQuaternion::from_euler_angles(0.0, 0.2, std::f64::consts::PI),
    ) * mount.link_from_optical;
    let config = RenderConfig {
        cull_back_faces: cull,
        simplify_cell_m,
        ..RenderConfig::default()
    };
    let mut renderer = CpuRenderer::new(&config)?;
    renderer.prepare(robot.link_meshes())?;
    // The full mesh, no culling: the reference for the silhouette's IoU.
    let mut reference = CpuRenderer::new(&RenderConfig::default())?;
    reference.prepare(robot.link_meshes())?;
    println!(
        "{}: {} triangles ({} drawn; cull {cull}, simplify {simplify_cell_m} m)",
        robot.name(),
        robot.triangle_count(),
        renderer.triangle_count()
    );
    let mut mapper = robot.joint_mapper();
    for (w, h) in [(160u32, 120u32), (320, 240), (640, 480)] {
        let k = Intrinsics::from_fov(w, h, 70.0)?;
        let mut out = RenderOutput::default();
        let (mut best, mut best_fk) = (f64::INFINITY, f64::INFINITY);
        let mut previous: Option<(Vec<Isometry3<f64>>, Isometry3<f64>)> = None;
        for rep in 0..=reps {
            let mut q = pose.clone();
            q[0] = 0.02 * rep as f64;
            let t = thread_cpu_ms();
            let positions = mapper.map(&names, &q)?.positions;
            let links = robot.forward(&positions)?;
            let camera_from_base = mount
                .camera_from_base(&links)
                .ok_or_else(|| anyhow::anyhow!("no camera pose"))?;
            let t_fk = thread_cpu_ms();
            if let Some((prev_links, prev_camera)) = &previous {
                renderer.render(
                    &RenderFrame {
                        intrinsics: &k,
                        current: RobotView {
                            camera_from_base,
                            base_from_link: &links,
                        },
                        previous: Some(RobotView {
                            camera_from_base: *prev_camera,
                            base_from_link: prev_links,
                        }),
                        shade: false,
                    },
                    &mut out,
                )?;
                let end = thread_cpu_ms();
                best = best.min(end - t);
                best_fk = best_fk.min(t_fk - t);
            }
            previous = Some((links, camera_from_base));
        }
        let (prev_links, prev_camera) = previous.ok_or_else(|| anyhow::anyhow!("no frame"))?;
        let mut full = RenderOutput::default();
        reference.render(
            &RenderFrame {
                intrinsics: &k,
                current: RobotView {
                    camera_from_base: prev_camera,
                    base_from_link: &prev_links,
                },
                previous: None,
                shade: false,
            },
            &mut full,
        )?;
        renderer.render(
            &RenderFrame {
                intrinsics: &k,
                current: RobotView {
                    camera_from_base: prev_camera,
                    base_from_link: &prev_links,
                },
                previous: None,
                shade: false,
            },
            &mut out,
        )?;
        let both = out
            .coverage
            .iter()
            .zip(&full.coverage)
            .filter(|(a, b)| **a && **b)
            .count();
        let either = out
            .coverage
            .iter()
            .zip(&full.coverage)
            .filter(|(a, b)| **a || **b)
            .count();
        println!(
            "{w}x{h}: step {best:.3} ms (FK + mapping {best_fk:.4} ms; min of {reps}), {:.1} % covered, silhouette IoU vs full mesh {:.4}",
            100.0 * out.covered_pixels() as f64 / f64::from(w * h),
            both as f64 / either.max(1) as f64
        );
    }
    Ok(())
}
