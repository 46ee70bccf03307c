//! Fourier-Mellin registration timings, single thread: a pair through a warm
//! [`Registrar`] (plans cached, both frames processed), a pair through the free
//! `register` (plans built per call) and the streaming `push` (one new frame per call).
#![allow(clippy::unwrap_used, clippy::expect_used, missing_docs)] // criterion_group! generates undocumented items.

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use std::hint::black_box;
use std::time::Duration;
use vamos::vision::registration::{Registrar, RegistrationParams, register};
use vamos::vision::synthetic::{self, Motion};

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("registration");
    g.sample_size(20)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(2));
    for &n in &[128usize, 256, 512] {
        let motion = Motion::Similarity {
            tx: 5.0,
            ty: -3.0,
            scale: 1.05,
            rotation_deg: 6.0,
        };
        let (a, b, _) = synthetic::pair(n, n, &motion, 1);
        let params = RegistrationParams::default();
        let mut r = Registrar::new(params.clone()).unwrap();
        g.bench_with_input(BenchmarkId::new("pair_cached_plans", n), &n, |bch, _| {
            bch.iter(|| r.register(black_box(&a), black_box(&b), None).unwrap())
        });
        g.bench_with_input(BenchmarkId::new("pair_fresh", n), &n, |bch, _| {
            bch.iter(|| register(black_box(&a), black_box(&b), None, &params).unwrap())
        });
        let mut s = Registrar::new(params.clone()).unwrap();
        let frames = [a.clone(), b.clone()];
        let mut k = 0usize;
        s.push(&frames[1], None).unwrap();
        g.bench_with_input(BenchmarkId::new("push", n), &n, |bch, _| {
            bch.iter(|| {
                k += 1;
                s.push(black_box(&frames[k % 2]), None).unwrap()
            })
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
