//! Flow-predictor timing: encoder and head latency at batch 1 and batched, and the
//! per-frame model cost of the cached predictor against the naive per-offset loop.
//!
//! Environment: `VAMOS_BENCH_MODEL` (bundle path; default the tiny test bundle
//! tests/fixtures/model/valid.vamos), `VAMOS_BENCH_THREADS` (intra-op threads, default 1),
//! `VAMOS_BENCH_SAMPLES` (M; default the bundle's). `benches/compare_model.py` times the
//! same work in Python onnxruntime.

// criterion_group! generates undocumented items.
#![allow(missing_docs)]

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;
use vamos::model::predictor::naive_score;
use vamos::model::rng::NormalRng;
use vamos::model::{FlowModel, LoadOptions, Predictor, PredictorParams};

fn env_usize(key: &str) -> Option<usize> {
    std::env::var(key).ok().and_then(|v| v.parse().ok())
}

fn bench_model(c: &mut Criterion) {
    let path = std::env::var_os("VAMOS_BENCH_MODEL").map_or_else(
        || PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/model/valid.vamos"),
        PathBuf::from,
    );
    let threads = env_usize("VAMOS_BENCH_THREADS").unwrap_or(1);
    let options = LoadOptions {
        intra_threads: threads,
        ..LoadOptions::default()
    };
    let model = match FlowModel::load(&path, &options) {
        Ok(m) => Arc::new(m),
        Err(e) => {
            eprintln!("cannot load {}: {e}", path.display());
            return;
        }
    };
    let params = PredictorParams::from_manifest(
        model.manifest(),
        env_usize("VAMOS_BENCH_SAMPLES").unwrap_or(0),
    );
    let d = model.dims();
    let offsets = params.b + 1;
    let rows = offsets * params.samples;
    let name = model.manifest().name.clone();
    eprintln!(
        "model {name}: C {} L {} S {}; A {} B {} M {}; {threads} thread(s)",
        d.channels, d.latent, d.size, params.a, params.b, params.samples
    );
    let mut rng = NormalRng::new(3);
    let mut frame = || -> Vec<f32> {
        (0..d.flow_len())
            .map(|_| (rng.normal() * 0.2).clamp(-0.5, 0.5) as f32)
            .collect()
    };
    let frames: Vec<Vec<f32>> = (0..params.a + params.b + 2).map(|_| frame()).collect();

    let mut group = c.benchmark_group(format!("model/{name}/{threads}t"));
    group.sample_size(20);
    group.warm_up_time(Duration::from_millis(500));
    group.measurement_time(Duration::from_secs(3));
    for batch in [1, offsets] {
        let input: Vec<f32> = frames[..batch].concat();
        group.bench_with_input(BenchmarkId::new("encoder", batch), &input, |b, input| {
            b.iter(|| model.encode(input, batch));
        });
    }
    let Ok(enc) = model.encode(&frames[0], 1) else {
        return;
    };
    for batch in [1, rows] {
        let features: Vec<f32> = (0..batch)
            .flat_map(|_| enc.features.iter().copied())
            .collect();
        let z: Vec<f32> = (0..batch)
            .flat_map(|_| enc.prior_mu.iter().copied())
            .collect();
        let mut out = Vec::new();
        group.bench_function(BenchmarkId::new("head", batch), |b| {
            b.iter(|| model.predict_into(&features, &z, batch, &mut out));
        });
    }
    // Steady state: the ring is full, every offset is available.
    let Ok(mut predictor) = Predictor::new(model.clone(), params, 1) else {
        return;
    };
    for f in &frames[..params.a + params.b] {
        let _ = predictor.push(f, None);
    }
    let current = &frames[params.a + params.b];
    group.bench_function("frame/cached", |b| {
        b.iter(|| predictor.push(current, None));
    });
    let t = params.a + params.b;
    let past: Vec<(usize, &[f32])> = (params.a..=params.a + params.b)
        .map(|n| (n, frames[t - n].as_slice()))
        .collect();
    let mut rng = NormalRng::new(1);
    group.bench_function("frame/naive", |b| {
        b.iter(|| naive_score(&model, &past, current, None, params.samples, &mut rng));
    });
    group.finish();
}

criterion_group!(benches, bench_model);
criterion_main!(benches);
