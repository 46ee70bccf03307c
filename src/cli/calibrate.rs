//! `vamos calibrate`: thresholds from nominal episodes, stored beside the profile.
//!
//! The computation is [`vamos::pipeline::calibration::calibrate`]; this scores the
//! episodes in parallel and writes the calibration beside the profile file.

use super::progress::Progress;
use super::score::{ScoreAll, ScoreRun, Setup, expand_episodes};
use anyhow::Result;
use std::path::PathBuf;
use vamos::config::Settings;
use vamos::pipeline::calibration::calibrate;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The profile; the calibration is written beside it (`<stem>.calibration.json`).
    #[arg(long)]
    pub profile: PathBuf,
    /// Nominal training episodes (.mcap files or folders).
    #[arg(required = true)]
    pub episodes: Vec<PathBuf>,
    /// Held-out nominal episodes for the conformal threshold.
    #[arg(long, num_args = 1..)]
    pub holdout: Vec<PathBuf>,
    /// Per-episode false-alarm budget of the conformal threshold.
    #[arg(long, default_value_t = 0.1)]
    pub alpha: f64,
    /// No progress bars (they are drawn on stderr only when it is a terminal).
    #[arg(long)]
    pub no_progress: bool,
}

/// Runs the calibration ([`vamos::pipeline::calibration`]) and saves it; prints it as
/// JSON on stdout.
pub fn run(settings: &Settings, opts: Args) -> Result<()> {
    let progress = Progress::new(opts.no_progress);
    let mut setup = Setup::load(settings, &opts.profile)?;
    let training = expand_episodes(&opts.episodes)?;
    let holdout = if opts.holdout.is_empty() {
        Vec::new()
    } else {
        expand_episodes(&opts.holdout)?
    };
    let model_sha256 = setup.model.as_ref().map(|m| m.sha256().to_string());
    let mut pass = 0;
    let outcome = calibrate(
        &training,
        &holdout,
        opts.alpha,
        model_sha256,
        &setup.config.clone(),
        |episodes, thresholds| {
            pass += 1;
            let what = if pass == 1 { "training" } else { "held-out" };
            eprintln!("scoring {} {what} episodes", episodes.len());
            setup.score_all(
                episodes,
                &ScoreRun::new(what, thresholds, f64::INFINITY, &progress),
            )
        },
    )?;
    // The notes (a conformal threshold that falls back to the training maximum, with
    // the numbers; learned depth; ...) on stderr: stdout is the calibration file's JSON.
    for note in &outcome.notes {
        eprintln!("note: {note}");
    }
    let calibration = outcome.calibration;
    let path = setup.profile.save_calibration(calibration.clone())?;
    println!("{}", serde_json::to_string_pretty(&calibration)?);
    eprintln!("calibration written to {}", path.display());
    Ok(())
}
