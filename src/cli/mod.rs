//! The sub-commands of the `vamos` binary: each `<command>.rs` owns its flags (a
//! `clap::Args` struct, or a `clap::Subcommand` enum for command groups) and its `run`;
//! `main.rs` only parses, loads the settings and dispatches. Helpers shared by several
//! commands are below.

pub mod calibrate;
pub mod config;
pub mod demo;
pub mod episode;
pub mod eval;
pub mod export;
pub mod flow;
pub mod health;
pub mod loadgen;
pub mod model;
pub mod progress;
pub mod register;
pub mod render;
pub mod robot;
pub mod score;
pub mod serve;
pub mod stream;
pub mod vision_demo;

use anyhow::{Context, Result};
use std::path::Path;
use vamos::vision::GrayImage;

/// A failure already reported on stdout (e.g. `vamos health` printing an unhealthy
/// status): the process exits with code 1 and prints nothing more.
#[derive(Debug, thiserror::Error)]
#[error("failed")]
pub struct Failed;

/// The multi-threaded tokio runtime of the async sub-commands.
pub fn async_runtime() -> Result<tokio::runtime::Runtime> {
    tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")
}

/// Worker threads: `n`, or one per core for 0.
pub fn resolve_threads(n: usize) -> usize {
    if n == 0 {
        std::thread::available_parallelism().map_or(1, |n| n.get())
    } else {
        n
    }
}

/// A rayon pool of `threads` workers.
pub fn pool(threads: usize) -> Result<rayon::ThreadPool> {
    Ok(rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()?)
}

/// The smallest and the median of `times` (sorted in place); NaN when empty.
pub fn min_median(times: &mut [f64]) -> (f64, f64) {
    times.sort_by(f64::total_cmp);
    (
        times.first().copied().unwrap_or(f64::NAN),
        times.get(times.len() / 2).copied().unwrap_or(f64::NAN),
    )
}

/// An image file as gray.
pub fn load_gray(path: &Path) -> Result<GrayImage> {
    Ok(GrayImage::load(path)?)
}

/// An error and its causes, joined by ": ", leaving out a cause whose text the message
/// already holds (many errors print their source in their own message).
pub fn error_text(e: &anyhow::Error) -> String {
    let mut out = String::new();
    for cause in e.chain() {
        let text = cause.to_string();
        if out.contains(&text) {
            continue;
        }
        if !out.is_empty() {
            out.push_str(": ");
        }
        out.push_str(&text);
    }
    out
}
