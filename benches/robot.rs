//! Robot description benches: forward kinematics per joint state (panda, kuka), joint-name
//! mapping, and loading the panda package (URDF + 18 OBJ meshes, ~9 MB).

// criterion_group! generates undocumented items.
#![allow(missing_docs)]

use criterion::{Criterion, criterion_group, criterion_main};
use std::hint::black_box;
use std::path::{Path, PathBuf};
use vamos::robot::{Robot, RobotConfig};

fn fixture(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/robot")
        .join(rel)
}

fn fk(c: &mut Criterion) {
    let cfg = RobotConfig::default();
    for (name, rel) in [
        ("panda", "franka_panda/panda.urdf"),
        ("kuka", "kuka_iiwa/model.urdf"),
    ] {
        let Ok(robot) = Robot::load(&fixture(rel), &cfg) else {
            eprintln!("cannot load {rel}; skipping");
            continue;
        };
        let values: Vec<f64> = (0..robot.joints().len())
            .map(|i| 0.1 * i as f64 - 0.3)
            .collect();
        let Ok(q) = robot.positions(values) else {
            continue;
        };
        let mut poses = Vec::new();
        c.bench_function(&format!("robot_fk/{name}"), |b| {
            b.iter(|| robot.forward_into(black_box(&q), &mut poses))
        });
        let names: Vec<String> = robot.joints().iter().map(|j| j.name.clone()).collect();
        let positions = vec![0.2; names.len()];
        let mut mapper = robot.joint_mapper();
        c.bench_function(&format!("robot_map_and_fk/{name}"), |b| {
            b.iter(|| {
                let m = mapper.map(black_box(&names), black_box(&positions));
                m.map(|m| robot.forward_into(&m.positions, &mut poses))
            })
        });
    }
}

fn load(c: &mut Criterion) {
    let cfg = RobotConfig::default();
    let mut group = c.benchmark_group("robot_load");
    group.sample_size(10);
    group.bench_function("panda_package", |b| {
        b.iter(|| Robot::load(black_box(&fixture("franka_panda")), &cfg))
    });
    group.finish();
}

criterion_group!(benches, fk, load);
criterion_main!(benches);
