//! The calibration of a profile from nominal episodes (`vamos calibrate` and the service's
//! calibration jobs run this one function; they differ only in how episodes are scored).
//!
//! 1. The training episodes are scored without thresholds; `e_c_thres` and `e_b_thres`
//!    are the maxima of `e_c` and `e_b` over them (the paper).
//! 2. With those thresholds, the largest fused score over the training frames is the
//!    `max` alarm threshold.
//! 3. The held-out nominal episodes are scored with the thresholds; the split-conformal
//!    threshold on their per-episode maximum fused score bounds the episode-level false-
//!    alarm probability by `alpha` ([`crate::eval::conformal_threshold`]).

use super::offline::EpisodeScores;
use super::profile::Calibration;
use super::scorer::FrameScore;
use crate::eval::{Thresholds, conformal_threshold, fuse, max_threshold};
use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

/// A calibration and what is worth telling about it.
#[derive(Debug, Clone)]
pub struct CalibrationOutcome {
    /// The calibration.
    pub calibration: Calibration,
    /// Remarks (no held-out episodes, no conformal threshold and why).
    pub notes: Vec<String>,
}

/// The largest fused score of an episode (0 when it has no frame).
pub fn episode_max(e: &EpisodeScores) -> f64 {
    e.frames.iter().map(|f| f.score).fold(0.0, f64::max)
}

/// Calibrates from `training` and `holdout` episodes (files), scoring them with `score`
/// (called with the episodes and the thresholds to score with: first the training
/// episodes with no thresholds, then the held-out ones, if any, with the fitted ones).
/// `model_sha256` identifies the model the scores come from.
pub fn calibrate<E>(
    training: &[PathBuf],
    holdout: &[PathBuf],
    alpha: f64,
    model_sha256: Option<String>,
    mut score: impl FnMut(&[PathBuf], Thresholds) -> Result<Vec<EpisodeScores>, E>,
) -> Result<CalibrationOutcome, E> {
    let train = score(training, Thresholds::default())?;
    let component = |f: fn(&FrameScore) -> Option<f64>| -> Vec<f64> {
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
    let mut notes = Vec::new();
    let conformal = if holdout.is_empty() {
        notes.push("no held-out episodes: only the maximum thresholds are calibrated".into());
        None
    } else {
        let held = score(holdout, thresholds)?;
        let maxima: Vec<f64> = held.iter().map(episode_max).collect();
        match conformal_threshold(&maxima, alpha) {
            Ok(c) => Some(c),
            Err(e) => {
                notes.push(format!("no conformal threshold: {e}"));
                None
            }
        }
    };
    let calibration = Calibration {
        created_unix_s: SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0, |d| d.as_secs()),
        model_sha256,
        training_episodes: train.iter().map(|e| e.name.clone()).collect(),
        calibration_episodes: holdout.iter().map(|p| stem(p)).collect(),
        training_frames,
        thresholds,
        score_max,
        conformal,
    };
    Ok(CalibrationOutcome { calibration, notes })
}

fn stem(p: &Path) -> String {
    p.file_stem().map_or_else(
        || p.display().to_string(),
        |s| s.to_string_lossy().into_owned(),
    )
}
