//! `vamos flow`: TV-L1 optical flow from image A to image B (forward flow, pixels).

use super::{load_gray, min_median, pool, resolve_threads};
use anyhow::{Context, Result};
use serde_json::json;
use std::path::PathBuf;
use std::time::Instant;
use vamos::config::Settings;
use vamos::vision::flow::{FlowEstimator, FlowParams};
use vamos::vision::flowio::{write_flo, write_flow_png};
use vamos::vision::preprocess::equalize_histogram;
use vamos::vision::{FlowField, GrayImage};

#[derive(clap::Args, Debug)]
pub struct Args {
    /// First image (PNG or JPEG; colour is converted to gray).
    pub a: PathBuf,
    /// Second image, same size.
    pub b: PathBuf,
    /// Colour-coded flow (Middlebury colour wheel), PNG.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Also write the raw field in Middlebury `.flo` format.
    #[arg(long)]
    pub raw: Option<PathBuf>,
    /// Parameter preset: `default` (OpenCV DualTVL1's defaults), `realtime`,
    /// `realtime-hq` or `balanced`; without it the settings' `[vision.flow]` apply.
    #[arg(long, value_parser = clap::builder::PossibleValuesParser::new(vamos::vision::flow::PRESET_NAMES))]
    pub preset: Option<String>,
    /// Worker threads (0 = one per core; default from the settings).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Histogram-equalise both images first (as the detection pipeline does).
    #[arg(long)]
    pub equalize: bool,
    /// Saturation magnitude of the colour coding in pixels (default: the largest).
    #[arg(long)]
    pub max_flow: Option<f32>,
    /// Compute the flow this many times (timing).
    #[arg(long, default_value_t = 1)]
    pub repeat: usize,
    /// Print a JSON line with the flow computation time on stdout.
    #[arg(long)]
    pub timing: bool,
}

/// Computes, writes and (with `--timing`) times the flow.
pub fn run(settings: &Settings, args: Args) -> Result<()> {
    let Args {
        a,
        b,
        output,
        raw,
        preset,
        threads,
        equalize,
        max_flow,
        repeat,
        timing,
    } = args;
    let params = match preset.as_deref() {
        Some(name) => FlowParams::preset(name)?,
        None => settings.vision.flow.clone(),
    };
    let threads = resolve_threads(threads.unwrap_or(settings.vision.threads));
    let (mut ia, mut ib) = (load_gray(&a)?, load_gray(&b)?);
    if equalize {
        ia = equalize_histogram(&ia)?;
        ib = equalize_histogram(&ib)?;
    }
    let pool = pool(threads)?;
    let mut times = Vec::new();
    let mut flow = None;
    // One estimator for every repeat: its buffers are reused, as in a stream.
    let mut est = FlowEstimator::new(params.clone())?;
    for _ in 0..repeat.max(1) {
        let start = Instant::now();
        let f = pool.install(|| flow_of(&mut est, &ia, &ib))?;
        times.push(start.elapsed().as_secs_f64() * 1e3);
        flow = Some(f);
    }
    let flow = flow.context("no flow computed")?;
    write_flow_png(&flow, max_flow, &output)?;
    if let Some(raw) = raw {
        write_flo(&flow, &raw)?;
    }
    let (min, median) = min_median(&mut times);
    tracing::info!(ms_min = min, ms_median = median, threads, "flow computed");
    if timing {
        println!(
            "{}",
            json!({
                "width": flow.width(), "height": flow.height(),
                "preset": preset.unwrap_or_else(|| "settings".into()),
                "threads": threads, "repeat": times.len(),
                "ms_min": min, "ms_median": median,
            })
        );
    }
    Ok(())
}

/// The flow `a -> b` from `est`, reset first (so it holds no earlier frame).
fn flow_of(est: &mut FlowEstimator, a: &GrayImage, b: &GrayImage) -> Result<FlowField> {
    est.reset();
    est.push(a)?;
    est.push(b)?
        .context("the estimator returned no flow for the second frame")
}
