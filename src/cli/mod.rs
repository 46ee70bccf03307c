//! The sub-commands of the `vamos` binary: each `<command>.rs` owns its flags (a
//! `clap::Args` struct, or a `clap::Subcommand` enum for command groups) and its `run`;
//! `main.rs` only parses, loads the settings and dispatches. Helpers shared by several
//! commands are below.

pub mod bridge;
pub mod calibrate;
pub mod config;
pub mod demo;
pub mod episode;
pub mod eval;
pub mod export;
pub mod flow;
pub mod health;
pub mod layout;
pub mod loadgen;
pub mod model;
pub mod profile;
pub mod progress;
pub mod register;
pub mod render;
pub mod robot;
pub mod schema;
pub mod score;
pub mod serve;
pub mod shell;
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

/// The `q`-quantile (0..=1) of ascending `sorted` samples: the sample at rank
/// `round((n - 1) q)`; `None` when there are none (NaN `q` reads the first).
///
/// Not hdrhistogram: its callers (`vamos loadgen`, the demo's report) keep every sample
/// anyway (for the maximum, the per-interval timeline and the per-episode tables), sort
/// once and read three order statistics exactly; a histogram would add a copy quantised
/// to its significant digits (values scaled to integers first) and save no memory.
pub fn percentile(sorted: &[f64], q: f64) -> Option<f64> {
    let last = sorted.len().checked_sub(1)?;
    let i = (last as f64 * q.clamp(0.0, 1.0)).round() as usize;
    sorted.get(i.min(last)).copied()
}

/// Fails at once when `path` cannot be written as a file later: its folder does not exist
/// (or is not a folder), or `path` is a folder. `flag` names the option in the message.
/// Commands call it before their work, so a typo does not cost a whole run.
pub fn check_output_file(flag: &str, path: &Path) -> Result<()> {
    if path.is_dir() {
        anyhow::bail!("{flag} {}: is a folder, not a file", path.display());
    }
    let parent = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    if !parent.is_dir() {
        anyhow::bail!(
            "{flag} {}: the folder {} does not exist",
            path.display(),
            parent.display()
        );
    }
    Ok(())
}

/// Fails at once when the output folder `path` can neither be used nor made: it is a
/// file, or a file stands where one of its missing parents would be made.
pub fn check_output_dir(flag: &str, path: &Path) -> Result<()> {
    let mut at = path;
    loop {
        if at.exists() {
            if !at.is_dir() {
                anyhow::bail!(
                    "{flag} {}: {} is a file, not a folder",
                    path.display(),
                    at.display()
                );
            }
            return Ok(());
        }
        match at.parent() {
            Some(p) if !p.as_os_str().is_empty() => at = p,
            _ => return Ok(()),
        }
    }
}

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

#[cfg(test)]
mod tests {
    use super::{check_output_dir, check_output_file, percentile};
    use std::path::Path;

    #[test]
    fn output_paths_are_checked_before_work() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("f.txt");
        std::fs::write(&file, "x").unwrap();
        // Files: the folder must exist; a folder is not a file.
        assert!(check_output_file("--json", &dir.path().join("x.json")).is_ok());
        assert!(check_output_file("--json", Path::new("x.json")).is_ok());
        let e = check_output_file("--json", &dir.path().join("no/x.json")).unwrap_err();
        assert!(e.to_string().contains("does not exist"), "{e}");
        assert!(check_output_file("--json", dir.path()).is_err());
        assert!(check_output_file("--json", &file.join("x.json")).is_err());
        // Folders: made later (with parents), unless a file is in the way.
        assert!(check_output_dir("--out", &dir.path().join("a/b/c")).is_ok());
        assert!(check_output_dir("--out", dir.path()).is_ok());
        assert!(check_output_dir("--out", &file).is_err());
        let e = check_output_dir("--out", &file.join("sub")).unwrap_err();
        assert!(e.to_string().contains("is a file"), "{e}");
    }

    #[test]
    fn percentile_reads_nearest_rank() {
        assert_eq!(percentile(&[], 0.5), None);
        assert_eq!(percentile(&[7.0], 0.99), Some(7.0));
        let v: Vec<f64> = (0..=100).map(f64::from).collect();
        assert_eq!(percentile(&v, 0.0), Some(0.0));
        assert_eq!(percentile(&v, 0.5), Some(50.0));
        assert_eq!(percentile(&v, 0.99), Some(99.0));
        assert_eq!(percentile(&v, 1.0), Some(100.0));
        // Out-of-range quantiles are clamped to the ends.
        assert_eq!(percentile(&v, 1.5), Some(100.0));
        assert_eq!(percentile(&[1.0, 2.0, 3.0, 4.0], 0.5), Some(3.0));
    }
}
