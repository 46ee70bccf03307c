//! `vamos demo --vision`: the vision core on synthetic image pairs with exact ground
//! truth: TV-L1 flow (two presets) and registration, their errors and timings.

use anyhow::{Context, Result};
use serde_json::json;
use std::path::Path;
use std::time::Instant;
use vamos::vision::flow::{FlowEstimator, FlowParams};
use vamos::vision::flowio::write_flow_png;
use vamos::vision::registration::{Registrar, RegistrationParams};
use vamos::vision::synthetic::{self, Motion};
use vamos::vision::{FlowField, GrayImage};

/// The vision core on synthetic pairs with exact ground truth: flow (both presets) and
/// registration, errors against the truth, timings; images to `out`.
pub fn run(
    out: &Path,
    width: usize,
    height: usize,
    threads: usize,
    reg: &RegistrationParams,
) -> Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let pool = pool(threads)?;
    let cases = [
        ("translation", Motion::Translation { dx: 2.5, dy: -1.25 }),
        (
            "camera_similarity",
            Motion::Similarity {
                tx: 3.0,
                ty: -2.0,
                scale: 1.03,
                rotation_deg: 2.0,
            },
        ),
        (
            "non_rigid",
            Motion::Smooth {
                amplitude_px: 3.0,
                seed: 11,
            },
        ),
        (
            "moving_square",
            Motion::MovingSquare {
                x: width as f64 * 0.35,
                y: height as f64 * 0.3,
                size_px: height as f64 / 3.0,
                dx: 3.0,
                dy: 2.0,
            },
        ),
    ];
    println!(
        "vamos demo: {width}x{height}, {threads} thread(s), output in {}",
        out.display()
    );
    println!(
        "{:<18} {:>10} {:>10} {:>12} {:>10} | registration (tx, ty, scale, rot) vs truth",
        "case", "AEE def", "ms def", "AEE realtime", "ms rt"
    );
    let mut registrar = Registrar::new(reg.clone())?;
    let mut summary = Vec::new();
    for (i, (name, motion)) in cases.iter().enumerate() {
        let (a, b, truth) = synthetic::pair(width, height, motion, 100 + i as u64);
        let valid = synthetic::moving_square_valid(width, height, motion, 2.0);
        let mut row = json!({ "case": name, "motion": format!("{motion:?}") });
        let mut cells = Vec::new();
        for preset in ["default", "realtime"] {
            let params = FlowParams::preset(preset)?;
            let start = Instant::now();
            let flow = pool.install(|| flow_of(&a, &b, &params))?;
            let ms = start.elapsed().as_secs_f64() * 1e3;
            let aee = flow
                .average_endpoint_error(&truth, valid.as_deref())
                .unwrap_or(f64::NAN);
            write_flow_png(&flow, None, &out.join(format!("{name}_flow_{preset}.png")))?;
            row[preset] = json!({ "aee_px": aee, "ms": ms });
            cells.push((aee, ms));
        }
        a.save_png(&out.join(format!("{name}_a.png")))?;
        b.save_png(&out.join(format!("{name}_b.png")))?;
        write_flow_png(&truth, None, &out.join(format!("{name}_flow_truth.png")))?;
        // The moving square stands in for the robot body: registration measures the
        // camera (background) motion with those pixels masked out, as the pipeline does.
        let mask = synthetic::moving_square_cover(width, height, motion, 2.0);
        let r = registrar.register(&a, &b, mask.as_deref())?;
        let t = &r.transform;
        let truth_t = match *motion {
            Motion::Translation { dx, dy } => Some((dx, dy, 1.0, 0.0)),
            Motion::Similarity {
                tx,
                ty,
                scale,
                rotation_deg,
            } => Some((tx, ty, scale, rotation_deg)),
            Motion::MovingSquare { .. } => Some((0.0, 0.0, 1.0, 0.0)),
            Motion::Smooth { .. } => None,
        };
        row["registration"] = json!({
            "tx": t.tx_px, "ty": t.ty_px, "scale": t.scale, "rotation_deg": t.rotation_deg,
            "confidence": r.confidence, "masked": mask.is_some(),
            "truth": truth_t.map(|(a, b, c, d)| json!([a, b, c, d])),
        });
        let truth_txt = truth_t.map_or("(no single similarity)".to_string(), |(a, b, c, d)| {
            format!("truth ({a:.2}, {b:.2}, {c:.3}, {d:.2})")
        }) + if mask.is_some() {
            ", moving square masked"
        } else {
            ""
        };
        println!(
            "{:<18} {:>10.3} {:>10.1} {:>12.3} {:>10.1} | ({:.2}, {:.2}, {:.3}, {:.2}) conf {:.2} {}",
            name,
            cells[0].0,
            cells[0].1,
            cells[1].0,
            cells[1].1,
            t.tx_px,
            t.ty_px,
            t.scale,
            t.rotation_deg,
            r.confidence,
            truth_txt
        );
        summary.push(row);
    }
    let path = out.join("summary.json");
    std::fs::write(&path, serde_json::to_string_pretty(&summary)?)
        .with_context(|| format!("cannot write {}", path.display()))?;
    println!("AEE: average endpoint error against the exact ground truth, pixels.");
    println!("wrote {}", path.display());
    Ok(())
}

fn flow_of(a: &GrayImage, b: &GrayImage, params: &FlowParams) -> Result<FlowField> {
    let mut est = FlowEstimator::new(params.clone())?;
    est.push(a)?;
    est.push(b)?
        .context("the estimator returned no flow for the second frame")
}

fn pool(threads: usize) -> Result<rayon::ThreadPool> {
    Ok(rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()?)
}
