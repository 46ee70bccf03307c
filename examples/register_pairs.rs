//! Registers PNG pairs with vamos and prints JSON results with timings, for
//! `benches/compare_registration.py`.
//!
//! Usage: `register_pairs A1.png B1.png [A2.png B2.png ...]` or
//! `register_pairs --json pairs.json` with `[["a.png", "b.png"], ...]`.
//! Prints a JSON array of `{"a", "b", "tx", "ty", "scale", "rotation_deg", "confidence",
//! "ms", "ms_fresh"}`: `ms` is the best of 5 runs through a warm `Registrar` (FFT plans
//! cached, both images processed), `ms_fresh` one call of the free `register` (plans
//! built in the call). Image decoding is not timed.

use std::time::Instant;

use anyhow::{Context, bail};
use vamos::vision::image::GrayImage;
use vamos::vision::registration::{Registrar, RegistrationParams, register};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let pairs: Vec<(String, String)> = if args.first().map(String::as_str) == Some("--json") {
        let path = args.get(1).context("--json needs a file")?;
        let text = std::fs::read_to_string(path).with_context(|| format!("reading {path}"))?;
        let list: Vec<(String, String)> = serde_json::from_str(&text)?;
        list
    } else {
        if args.is_empty() || !args.len().is_multiple_of(2) {
            bail!("usage: register_pairs A.png B.png [A2.png B2.png ...] | --json pairs.json");
        }
        args.chunks(2)
            .map(|c| (c[0].clone(), c[1].clone()))
            .collect()
    };
    let params = RegistrationParams::default();
    let mut r = Registrar::new(params.clone())?;
    let mut out = Vec::new();
    for (pa, pb) in pairs {
        let a = GrayImage::load(pa.as_ref())?;
        let b = GrayImage::load(pb.as_ref())?;
        let t0 = Instant::now();
        let fresh = register(&a, &b, None, &params)?;
        let ms_fresh = t0.elapsed().as_secs_f64() * 1e3;
        let mut best = f64::INFINITY;
        let mut reg = fresh;
        for _ in 0..5 {
            let t = Instant::now();
            reg = r.register(&a, &b, None)?;
            best = best.min(t.elapsed().as_secs_f64() * 1e3);
        }
        out.push(serde_json::json!({
            "a": pa, "b": pb,
            "tx": reg.transform.tx_px, "ty": reg.transform.ty_px,
            "scale": reg.transform.scale, "rotation_deg": reg.transform.rotation_deg,
            "confidence": reg.confidence, "ms": best, "ms_fresh": ms_fresh,
        }));
    }
    println!("{}", serde_json::to_string_pretty(&out)?);
    Ok(())
}
