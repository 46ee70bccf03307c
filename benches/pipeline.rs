//! The full per-frame pipeline ([`vamos::pipeline::Scorer::push`]) on 640x480 input
//! images: the franka_panda fixture seen by a fixed camera (the arm moving), a textured
//! background drifting by 1 px per frame, joint states every frame, and the flow
//! predictor. Per configuration it prints the mean wall time of each stage over the
//! measured frames, then criterion times the whole push.
//!
//! Environment: `VAMOS_BENCH_MODEL` (bundle; default the tiny test bundle
//! tests/fixtures/model/valid.vamos; use `vamos-train export-random` for the paper-size
//! network), `VAMOS_BENCH_SIZES` (processing sizes, default `320x240,640x480`),
//! `VAMOS_BENCH_PRESETS` (TV-L1 presets, default `default,realtime`).

// criterion_group! generates undocumented items.
#![allow(missing_docs)]
// A bench set-up failure is a bench failure.
#![allow(clippy::expect_used)]

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;
use vamos::eval::Thresholds;
use vamos::model::{FlowModel, LoadOptions};
use vamos::pipeline::{
    FlowVariant, FrameInput, JointInput, PipelineConfig, RobotSetup, Scorer, ScorerParts,
    StageTimings,
};
use vamos::robot::render::{RenderBackend, RenderConfig};
use vamos::robot::{CameraConvention, Intrinsics, Robot, RobotConfig};
use vamos::vision::GrayImage;
use vamos::vision::flow::FlowParams;
use vamos::vision::preprocess::NetworkInputParams;
use vamos::vision::registration::RegistrationParams;
use vamos::vision::synthetic::Texture;

const FRAMES: usize = 24;

fn robot_setup() -> RobotSetup {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/robot/franka_panda");
    let robot = Robot::load(&path, &RobotConfig::default()).expect("the panda fixture loads");
    // The camera of examples/robot_step.rs: 1.2 m in front of the base, 0.5 m up.
    let root = robot.links()[robot.root()].clone();
    let mut mount = robot
        .camera(&root, CameraConvention::Body)
        .expect("root link");
    mount.link_from_optical = Isometry3::from_parts(
        Translation3::new(1.2, 0.0, 0.5),
        UnitQuaternion::from_euler_angles(0.0, 0.2, std::f64::consts::PI),
    ) * mount.link_from_optical;
    RobotSetup {
        robot: Arc::new(robot),
        mount,
        intrinsics: Some(Intrinsics::from_fov(640, 480, 70.0).expect("valid intrinsics")),
    }
}

fn stream() -> (Vec<GrayImage>, Vec<String>, Vec<Vec<f64>>) {
    let texture = Texture::random(9);
    let images = (0..FRAMES)
        .map(|k| {
            GrayImage::from_fn(640, 480, |x, y| {
                texture.eval(x as f64 - k as f64, y as f64) as f32
            })
        })
        .collect();
    let names: Vec<String> = (1..=7).map(|i| format!("panda_joint{i}")).collect();
    let joints = (0..FRAMES)
        .map(|k| vec![0.02 * k as f64, -0.3, 0.0, -2.0, 0.0, 1.8, 0.0])
        .collect();
    (images, names, joints)
}

fn scorer(setup: &RobotSetup, model: &Arc<FlowModel>, w: usize, h: usize, preset: &str) -> Scorer {
    let mut config = PipelineConfig::default();
    config.frames.width = w;
    config.frames.height = h;
    config.frames.variant = FlowVariant::Masked;
    Scorer::new(ScorerParts {
        config,
        flow: FlowParams::preset(preset).expect("known preset"),
        registration: RegistrationParams::default(),
        network: NetworkInputParams::default(),
        render: RenderConfig {
            backend: RenderBackend::Cpu,
            ..RenderConfig::default()
        },
        robot: Some(setup.clone()),
        model: Some(model.clone()),
        samples: 0,
        seed: 1,
        thresholds: Thresholds::paper(Some(1e9), Some(1e9)),
        alarm_threshold: f64::INFINITY,
        heatmaps: false,
    })
    .expect("scorer")
}

fn mean_stages(t: &[StageTimings]) -> String {
    let n = t.len().max(1) as f64;
    let ms =
        |f: &dyn Fn(&StageTimings) -> u64| t.iter().map(|s| f(s) as f64).sum::<f64>() / n / 1e3;
    format!(
        "kinematics {:.2} ms, render {:.2}, resize+equalise {:.2}, registration {:.2}, flow {:.2}, \
         network input {:.2}, e_c {:.2}, e_b {:.2}, model {:.2}; total {:.2} ms",
        ms(&|s| s.kinematics_us),
        ms(&|s| s.render_us),
        ms(&|s| s.front_end.prepare_us),
        ms(&|s| s.front_end.registration_us),
        ms(&|s| s.front_end.flow_us),
        ms(&|s| s.front_end.network_input_us),
        ms(&|s| s.camera_us),
        ms(&|s| s.body_us),
        ms(&|s| s.model_us),
        ms(&|s| s.total_us),
    )
}

fn bench_pipeline(c: &mut Criterion) {
    let path = std::env::var_os("VAMOS_BENCH_MODEL").map_or_else(
        || PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/model/valid.vamos"),
        PathBuf::from,
    );
    let model = match FlowModel::load(&path, &LoadOptions::default()) {
        Ok(m) => Arc::new(m),
        Err(e) => {
            eprintln!("cannot load {}: {e}", path.display());
            return;
        }
    };
    let sizes = std::env::var("VAMOS_BENCH_SIZES").unwrap_or_else(|_| "320x240,640x480".into());
    let presets =
        std::env::var("VAMOS_BENCH_PRESETS").unwrap_or_else(|_| "default,realtime".into());
    let setup = robot_setup();
    let (images, names, joints) = stream();
    eprintln!(
        "model {} ({}), franka_panda {} triangles, 640x480 input, masked variant",
        model.manifest().name,
        path.display(),
        setup.robot.triangle_count()
    );
    let mut group = c.benchmark_group("pipeline");
    group.sample_size(10);
    group.measurement_time(Duration::from_secs(20));
    for size in sizes.split(',') {
        let Some((w, h)) = size
            .split_once('x')
            .and_then(|(w, h)| Some((w.parse::<usize>().ok()?, h.parse::<usize>().ok()?)))
        else {
            eprintln!("bad size {size}");
            continue;
        };
        for preset in presets.split(',') {
            let mut s = scorer(&setup, &model, w, h, preset);
            // Warm up past the predictor's history, then record the stage times.
            let mut k = 0usize;
            let mut stamp = 0i64;
            let mut push = |s: &mut Scorer| {
                let i = k % FRAMES;
                k += 1;
                stamp += 100_000_000;
                s.push(&FrameInput {
                    stamp_ns: stamp,
                    image: &images[i],
                    joints: Some(JointInput {
                        names: &names,
                        positions: &joints[i],
                        efforts: &[],
                    }),
                    intrinsics: None,
                    depth: None,
                })
                .expect("push")
                .expect("stride 1")
            };
            let mut stages = Vec::new();
            for _ in 0..FRAMES {
                let f = push(&mut s);
                if !f.warming_up {
                    stages.push(f.timings);
                }
            }
            eprintln!("{size} {preset}: {}", mean_stages(&stages));
            group.bench_function(BenchmarkId::new(preset, size), |b| b.iter(|| push(&mut s)));
        }
    }
    group.finish();
}

criterion_group!(benches, bench_pipeline);
criterion_main!(benches);
