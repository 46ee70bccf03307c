//! Minimum-of-N timings of the flow predictor's work, printed as one JSON object: the
//! same measurements and statistic as `benches/compare_model.py` (Python onnxruntime), so
//! the two can be compared on a noisy machine. Beyond Python's keys: which head runs
//! (`head_backend`), the native head's rows and projection when it runs
//! (`native_head_<rows>_ms`, `native_project_ms`), and the cached frame with the head
//! forced to ONNX Runtime (`frame_cached_onnx_head_ms`).
//!
//! `cargo run --release --example model_time -- [BUNDLE] [THREADS] [REPEAT]`
//! (default: the tiny test bundle, 1 thread, 50 repeats; M from VAMOS_BENCH_SAMPLES or the
//! bundle).

use anyhow::{Context, Result};
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;
use vamos::model::predictor::naive_score;
use vamos::model::rng::NormalRng;
use vamos::model::{BatchItem, FlowModel, LoadOptions, Predictor, PredictorParams, push_batch};

fn best_ms(repeat: usize, mut f: impl FnMut() -> Result<()>) -> Result<f64> {
    f()?;
    let mut best = f64::INFINITY;
    for _ in 0..repeat {
        let t = Instant::now();
        f()?;
        best = best.min(t.elapsed().as_secs_f64() * 1e3);
    }
    Ok(best)
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let path = args.get(1).map_or_else(
        || PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/model/valid.vamos"),
        PathBuf::from,
    );
    let threads: usize = args.get(2).map_or(Ok(1), |s| s.parse())?;
    let repeat: usize = args.get(3).map_or(Ok(50), |s| s.parse())?;
    let samples = std::env::var("VAMOS_BENCH_SAMPLES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(0);
    let options = LoadOptions {
        intra_threads: threads,
        ..LoadOptions::default()
    };
    let model = Arc::new(FlowModel::load(&path, &options).context("loading the bundle")?);
    let p = PredictorParams::from_manifest(model.manifest(), samples);
    let d = model.dims();
    let (offsets, rows) = (p.b + 1, (p.b + 1) * p.samples);
    let mut rng = NormalRng::new(3);
    let frames: Vec<Vec<f32>> = (0..p.a + p.b + 2)
        .map(|_| {
            (0..d.flow_len())
                .map(|_| (rng.normal() * 0.2).clamp(-0.5, 0.5) as f32)
                .collect()
        })
        .collect();
    let mut out = serde_json::json!({
        "bundle": path.display().to_string(), "threads": threads,
        "a": p.a, "b": p.b, "m": p.samples,
    });
    for batch in [1, offsets] {
        let input = frames[..batch].concat();
        out[format!("encoder_{batch}_ms")] = best_ms(repeat, || {
            model.encode(&input, batch)?;
            Ok(())
        })?
        .into();
    }
    let enc = model.encode(&frames[0], 1)?;
    let mut buf = Vec::new();
    for batch in [1, rows] {
        let features: Vec<f32> = (0..batch)
            .flat_map(|_| enc.features.iter().copied())
            .collect();
        let z: Vec<f32> = (0..batch)
            .flat_map(|_| enc.prior_mu.iter().copied())
            .collect();
        out[format!("head_{batch}_ms")] = best_ms(repeat, || {
            model.predict_into(&features, &z, batch, &mut buf)?;
            Ok(())
        })?
        .into();
    }
    let (head, _) = model.head_backend();
    out["head_backend"] = head.into();
    if let Some(native) = model.native_head() {
        let projected = native.project(&enc.features);
        let mut row = vec![0.0f32; d.flow_len()];
        let mut scratch = vamos::model::head::HeadScratch::default();
        out["native_project_ms"] = best_ms(repeat, || {
            std::hint::black_box(native.project(&enc.features));
            Ok(())
        })?
        .into();
        out[format!("native_head_{rows}_ms")] = best_ms(repeat, || {
            for _ in 0..rows {
                native.predict_row(&projected, &enc.prior_mu, &mut row, &mut scratch);
            }
            Ok(())
        })?
        .into();
    }
    let t = p.a + p.b;
    let current = &frames[t];
    // The cached predictor with the configured head, and with ONNX Runtime's head.
    let onnx_head = Arc::new(FlowModel::load(
        &path,
        &LoadOptions {
            head: vamos::model::HeadBackend::Onnx,
            ..options
        },
    )?);
    for (key, m) in [
        ("frame_cached_ms", &model),
        ("frame_cached_onnx_head_ms", &onnx_head),
    ] {
        let mut predictor = Predictor::new(m.clone(), p, 1)?;
        for f in &frames[..p.a + p.b] {
            predictor.push(f, None)?;
        }
        out[key] = best_ms(repeat, || {
            predictor.push(current, None)?;
            Ok(())
        })?
        .into();
    }
    let past: Vec<(usize, &[f32])> = (p.a..=p.a + p.b)
        .map(|n| (n, frames[t - n].as_slice()))
        .collect();
    let mut rng = NormalRng::new(1);
    out["frame_naive_ms"] = best_ms(repeat, || {
        naive_score(&model, &past, current, None, p.samples, &mut rng)?;
        Ok(())
    })?
    .into();
    // Four sessions in steady state: one push each vs one push_batch for all.
    let sessions = 4;
    let mut preds: Vec<Predictor> = (0..sessions)
        .map(|s| Predictor::new(model.clone(), p, s as u64))
        .collect::<Result<_, _>>()?;
    for pr in &mut preds {
        for f in &frames[..p.a + p.b] {
            pr.push(f, None)?;
        }
    }
    out["sessions_4_single_ms"] = best_ms(repeat, || {
        for pr in &mut preds {
            pr.push(current, None)?;
        }
        Ok(())
    })?
    .into();
    out["sessions_4_batched_ms"] = best_ms(repeat, || {
        let mut items: Vec<BatchItem> = preds
            .iter_mut()
            .map(|pr| BatchItem {
                predictor: pr,
                input: current,
                mask: None,
            })
            .collect();
        for r in push_batch(&mut items) {
            r?;
        }
        Ok(())
    })?
    .into();
    println!("{}", serde_json::to_string_pretty(&out)?);
    Ok(())
}
