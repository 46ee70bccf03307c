//! `vamos calibrate`: thresholds from nominal episodes, stored beside the profile.
//!
//! 1. The training episodes are scored without thresholds; `e_c_thres` and `e_b_thres`
//!    are the maxima of `e_c` and `e_b` over them (the paper).
//! 2. With those thresholds, the largest fused score over the training frames is the
//!    `max` alarm threshold.
//! 3. The held-out nominal episodes are scored with the thresholds; the split-conformal
//!    threshold on their per-episode maximum fused score bounds the episode-level false-
//!    alarm probability by `alpha` ([`vamos::eval::conformal_threshold`]).

use super::score::{ScoreAll, Setup, expand_episodes};
use anyhow::Result;
use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};
use vamos::config::Settings;
use vamos::eval::{Thresholds, conformal_threshold, fuse, max_threshold};
use vamos::pipeline::Calibration;
use vamos::pipeline::offline::EpisodeScores;

/// Options of `vamos calibrate`.
pub struct CalibrateOptions {
    /// The profile file.
    pub profile: PathBuf,
    /// Nominal training episodes (files or folders).
    pub episodes: Vec<PathBuf>,
    /// Held-out nominal episodes for the conformal threshold.
    pub holdout: Vec<PathBuf>,
    /// Per-episode false-alarm budget.
    pub alpha: f64,
}

/// Runs the calibration and saves it; prints it as JSON on stdout.
pub fn run(settings: &Settings, opts: CalibrateOptions) -> Result<()> {
    let mut setup = Setup::load(settings, &opts.profile)?;
    let training = expand_episodes(&opts.episodes)?;
    let holdout = if opts.holdout.is_empty() {
        Vec::new()
    } else {
        expand_episodes(&opts.holdout)?
    };
    eprintln!("scoring {} training episodes", training.len());
    let train = setup.score_all(
        &training,
        Thresholds::default(),
        f64::INFINITY,
        None,
        None,
        None,
    )?;
    let component = |f: fn(&vamos::pipeline::FrameScore) -> Option<f64>| -> Vec<f64> {
        train
            .iter()
            .flat_map(|e| e.frames.iter().filter_map(f))
            .collect()
    };
    let thresholds = Thresholds {
        e_c: max_threshold(&component(|f| f.e_c)),
        e_b: max_threshold(&component(|f| f.e_b)),
    };
    let score_max = train
        .iter()
        .flat_map(|e| &e.frames)
        .map(|f| fuse(f.e_c, f.e_b, f.e_o, &thresholds).score)
        .fold(0.0, f64::max);
    let training_frames = train.iter().map(|e| e.frames.len()).sum();
    let conformal = if holdout.is_empty() {
        eprintln!("no --holdout episodes: only the maximum thresholds are calibrated");
        None
    } else {
        eprintln!("scoring {} held-out episodes", holdout.len());
        let held = setup.score_all(&holdout, thresholds, f64::INFINITY, None, None, None)?;
        let maxima: Vec<f64> = held.iter().map(episode_max).collect();
        match conformal_threshold(&maxima, opts.alpha) {
            Ok(c) => Some(c),
            Err(e) => {
                eprintln!("no conformal threshold: {e}");
                None
            }
        }
    };
    let calibration = Calibration {
        created_unix_s: SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0, |d| d.as_secs()),
        model_sha256: setup.model.as_ref().map(|m| m.sha256().to_string()),
        training_episodes: names(&train),
        calibration_episodes: holdout.iter().map(|p| stem(p)).collect(),
        training_frames,
        thresholds,
        score_max,
        conformal,
    };
    let path = setup.profile.save_calibration(calibration.clone())?;
    println!("{}", serde_json::to_string_pretty(&calibration)?);
    eprintln!("calibration written to {}", path.display());
    Ok(())
}

/// The largest fused score of an episode (0 when it has no frame).
pub fn episode_max(e: &EpisodeScores) -> f64 {
    e.frames.iter().map(|f| f.score).fold(0.0, f64::max)
}

fn names(e: &[EpisodeScores]) -> Vec<String> {
    e.iter().map(|e| e.name.clone()).collect()
}

fn stem(p: &Path) -> String {
    p.file_stem().map_or_else(
        || p.display().to_string(),
        |s| s.to_string_lossy().into_owned(),
    )
}
