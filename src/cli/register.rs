//! `vamos register`: Fourier-Mellin registration of A onto B; prints one JSON object.

use super::{load_gray, min_median};
use anyhow::{Context, Result, bail};
use serde_json::json;
use std::path::PathBuf;
use std::time::Instant;
use vamos::config::Settings;
use vamos::vision::registration::Registrar;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// First image.
    pub a: PathBuf,
    /// Second image, same size.
    pub b: PathBuf,
    /// Pixels to ignore (non-zero = ignore), same size, e.g. the robot body.
    #[arg(long)]
    pub mask: Option<PathBuf>,
    /// Register this many times (timing).
    #[arg(long, default_value_t = 1)]
    pub repeat: usize,
    /// Add `ms_min` and `ms_median` of the registration alone to the JSON.
    #[arg(long)]
    pub timing: bool,
}

/// Registers (`--repeat` times) and prints the transform.
pub fn run(settings: &Settings, args: Args) -> Result<()> {
    let Args {
        a,
        b,
        mask,
        repeat,
        timing,
    } = args;
    let (ia, ib) = (load_gray(&a)?, load_gray(&b)?);
    let mask = match mask {
        Some(path) => {
            let m = load_gray(&path)?;
            if m.size() != ia.size() {
                bail!(
                    "mask {} is {}x{} but the images are {}x{}",
                    path.display(),
                    m.width(),
                    m.height(),
                    ia.width(),
                    ia.height()
                );
            }
            Some(m.data().iter().map(|&v| v > 0.0).collect::<Vec<bool>>())
        }
        None => None,
    };
    let mut registrar = Registrar::new(settings.vision.registration.clone())?;
    let mut times = Vec::new();
    let mut result = None;
    for _ in 0..repeat.max(1) {
        let start = Instant::now();
        result = Some(registrar.register(&ia, &ib, mask.as_deref())?);
        times.push(start.elapsed().as_secs_f64() * 1e3);
    }
    let r = result.context("no registration computed")?;
    let mut out = json!({
        "tx": r.transform.tx_px, "ty": r.transform.ty_px, "scale": r.transform.scale,
        "rotation_deg": r.transform.rotation_deg, "confidence": r.confidence,
    });
    if timing {
        let (min, median) = min_median(&mut times);
        out["ms_min"] = json!(min);
        out["ms_median"] = json!(median);
    }
    println!("{out}");
    Ok(())
}
