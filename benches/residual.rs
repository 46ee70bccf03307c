//! The detectors beyond the paper, per frame at 320x240 (issue "detection beyond the
//! paper"; budget: at most 5 ms per frame on one core): the scene residual `e_r` (expected
//! image flow from two camera poses, the robot's masks grown, normal-flow residual cells,
//! nominal normalisation and block pooling), the per-pixel body residual and the kinematic
//! novelty `e_k` (nearest of the nominal robot states).

// criterion_group! generates undocumented items.
#![allow(missing_docs)]
// A bench whose fixed set-up fails has nothing to measure.
#![allow(clippy::expect_used)]

use criterion::{Criterion, criterion_group, criterion_main};
use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use std::hint::black_box;
use vamos::eval::{CellStats, Pooling, StateReference, pool_cells};
use vamos::pipeline::residual::{body_residual, cell_grid, grow_union, scene_cells};
use vamos::robot::Intrinsics;
use vamos::robot::camera_motion::{Depth, expected_image_flow};
use vamos::vision::synthetic::Texture;
use vamos::vision::{DepthImage, FlowField, GrayImage};

const W: usize = 320;
const H: usize = 240;

fn bench_residual(c: &mut Criterion) {
    let k = Intrinsics::from_fov(W as u32, H as u32, 60.0).expect("valid intrinsics");
    let previous = Isometry3::identity();
    let current = Isometry3::from_parts(
        Translation3::new(0.004, -0.002, 0.001),
        UnitQuaternion::from_euler_angles(0.002, 0.01, -0.003),
    );
    let texture = Texture::random(3);
    let image = GrayImage::from_fn(W, H, |x, y| texture.eval(x as f64, y as f64) as f32);
    // Observed: the expected motion plus a little noise and a moving patch.
    let mut expected = FlowField::zeros(0, 0);
    expected_image_flow(&previous, &current, &k, Depth::Assumed, 1.0, &mut expected)
        .expect("finite poses");
    let observed = FlowField::from_fn(W, H, |x, y| {
        let (u, v) = expected.get(x, y);
        let n = ((x * 7 + y * 13) % 11) as f32 * 0.02;
        if (200..230).contains(&x) && (40..70).contains(&y) {
            (u + n, v + 3.0)
        } else {
            (u + n, v - n)
        }
    });
    // A robot over the lower left quarter, in both frames.
    let mask: Vec<bool> = (0..W * H).map(|i| i % W < 140 && i / W > 100).collect();
    let previous_mask: Vec<bool> = (0..W * H).map(|i| i % W < 136 && i / W > 104).collect();
    let (columns, rows) = cell_grid(W, H, 8);
    let nominal: Vec<Vec<f32>> = (0..50)
        .map(|i| {
            (0..columns * rows)
                .map(|c| 0.1 + ((i * 31 + c * 7) % 17) as f32 * 0.01)
                .collect()
        })
        .collect();
    let refs: Vec<&[f32]> = nominal.iter().map(Vec::as_slice).collect();
    let stats = CellStats::fit(columns, rows, &refs).expect("50 maps of one size");
    let pooling = Pooling { top_fraction: 0.01 };

    // The image the flow ends on, for the photometric check (the default).
    let target = GrayImage::from_fn(W, H, |x, y| {
        let (u, v) = expected.get(x, y);
        texture.eval(x as f64 - f64::from(u), y as f64 - f64::from(v)) as f32
    });
    // A 640x480 depth image (metres, a slanted floor with a box on it), resampled to the
    // processing size as the scorer keeps it, then used for the expected flow.
    let depth = DepthImage::new(
        2 * W,
        2 * H,
        (0..4 * W * H)
            .map(|i| {
                let (x, y) = (i % (2 * W), i / (2 * W));
                if (300..400).contains(&x) && (200..300).contains(&y) {
                    0.6
                } else {
                    2.0 - y as f32 / (2 * H) as f32
                }
            })
            .collect(),
    )
    .expect("a 640x480 depth image");
    let mut flow = FlowField::zeros(0, 0);
    let mut kept = Vec::new();
    for (name, target, depth) in [
        ("residual/scene_e_r_320x240", Some(&target), None),
        ("residual/scene_e_r_no_photometric_320x240", None, None),
        (
            "residual/scene_e_r_depth_320x240",
            Some(&target),
            Some(&depth),
        ),
    ] {
        c.bench_function(name, |b| {
            b.iter(|| {
                let depth = match depth {
                    Some(d) => {
                        d.resample_into(W, H, &mut kept);
                        Depth::Image(&kept)
                    }
                    None => Depth::Assumed,
                };
                expected_image_flow(&previous, &current, &k, depth, 1.0, &mut flow)
                    .expect("finite poses");
                let exclude = grow_union(&mask, &previous_mask, W, H, 3);
                let cells = scene_cells(&observed, &flow, &exclude, 8, Some(&image), target);
                black_box(pool_cells(
                    &cells,
                    columns,
                    rows,
                    Some(stats.at(None)),
                    pooling,
                    None,
                ))
            })
        });
    }
    let rendered = FlowField::from_fn(W, H, |x, y| {
        if mask[y * W + x] {
            (1.5, -0.5)
        } else {
            (f32::NAN, f32::NAN)
        }
    });
    c.bench_function("residual/body_quantile_320x240", |b| {
        b.iter(|| black_box(body_residual(&rendered, &mask, &observed, 0.9, 0.5)))
    });
    // e_k: 40 nominal episodes of 110 frames; the default state (10 joints, positions and
    // velocities: 20 values) and the `links` state of a 15-link robot (270 values).
    for (name, dims) in [("kinematics_e_k_joints", 20), ("kinematics_e_k_links", 270)] {
        let episodes: Vec<Vec<Vec<f32>>> = (0..40)
            .map(|e| {
                (0..110)
                    .map(|f| {
                        (0..dims)
                            .map(|d| ((e * 7 + f * 13 + d * 31) % 97) as f32 * 0.01)
                            .collect()
                    })
                    .collect()
            })
            .collect();
        let reference = StateReference::fit(&episodes, dims, None).expect("states");
        let query: Vec<f32> = (0..dims).map(|d| (d % 5) as f32 * 0.2).collect();
        c.bench_function(
            &format!("residual/{name}_{}x{dims}", reference.len()),
            |b| b.iter(|| black_box(reference.distance(&query))),
        );
    }
}

criterion_group!(benches, bench_residual);
criterion_main!(benches);
