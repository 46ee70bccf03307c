//! The calibration of a profile from nominal episodes (`vamos calibrate` and the service's
//! calibration jobs run this one function; they differ only in how episodes are scored).
//!
//! 1. The training episodes are scored without thresholds; `e_c_thres` and `e_b_thres`
//!    are the maxima of `e_c` and `e_b` over them (the paper).
//! 2. The scene residual's per-cell statistics are fitted on the training frames' cell
//!    maps, their `e_r` pooled again with them, and each detector's nominal scale
//!    (median, 99th percentile) fitted on the training frames (calibrated fusion).
//! 3. With all that, the largest fused score over the training frames is the `max` alarm
//!    threshold.
//! 4. The held-out nominal episodes are scored with the thresholds; the split-conformal
//!    threshold on their per-episode maximum fused score bounds the episode-level false-
//!    alarm probability by `alpha` ([`crate::eval::conformal_threshold`]).

use super::PipelineConfig;
use super::offline::EpisodeScores;
use super::profile::Calibration;
use super::scorer::FrameScore;
use crate::eval::{
    CellStats, Components, NominalScales, Pooling, Thresholds, conformal_threshold, fuse_frame,
    max_threshold, pool_cells,
};
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
    e.frames
        .iter()
        .map(|f| f.score)
        .reduce(f64::max)
        .unwrap_or(0.0)
}

/// Calibrates from `training` and `holdout` episodes (files), scoring them with `score`
/// (called with the episodes and the thresholds to score with: first the training
/// episodes with no thresholds, then the held-out ones, if any, with the fitted ones).
/// `model_sha256` identifies the model the scores come from; `pipeline` is the profile's
/// (its fusion and residual pooling).
pub fn calibrate<E>(
    training: &[PathBuf],
    holdout: &[PathBuf],
    alpha: f64,
    model_sha256: Option<String>,
    pipeline: &PipelineConfig,
    mut score: impl FnMut(&[PathBuf], Thresholds) -> Result<Vec<EpisodeScores>, E>,
) -> Result<CalibrationOutcome, E> {
    let train = score(training, Thresholds::default())?;
    let mut notes = Vec::new();
    let frames: Vec<&FrameScore> = train.iter().flat_map(|e| &e.frames).collect();
    let component = |f: fn(&FrameScore) -> Option<f64>| -> Vec<f64> {
        frames.iter().filter_map(|x| f(x)).collect()
    };
    let scene = fit_scene(&frames, &mut notes);
    let pooling = Pooling {
        top_fraction: pipeline.residual.top_fraction,
    };
    // e_r of the training frames, pooled again with the fitted statistics.
    let e_r: Vec<Option<f64>> = frames
        .iter()
        .map(|f| match (&f.scene_cells, &scene) {
            (Some(cells), Some(stats)) => pool_cells(
                cells,
                f.scene_grid.0,
                f.scene_grid.1,
                Some(stats),
                pooling,
                None,
            ),
            _ => f.e_r,
        })
        .collect();
    let e_r_values: Vec<f64> = e_r.iter().flatten().copied().collect();
    let scales = NominalScales::fit(
        &component(|f| f.e_c),
        &component(|f| f.e_b),
        &e_r_values,
        &component(|f| f.e_o),
    );
    let thresholds = Thresholds {
        e_c: max_threshold(&component(|f| f.e_c)),
        e_b: max_threshold(&component(|f| f.e_b)),
        scales: Some(scales),
        scene,
    };
    let score_max = frames
        .iter()
        .zip(&e_r)
        .map(|(f, &e_r)| {
            let c = Components {
                e_c: f.e_c,
                e_b: f.e_b,
                e_r,
                e_o: f.e_o,
            };
            fuse_frame(&c, &thresholds, pipeline.fusion).score
        })
        .fold(f64::NEG_INFINITY, f64::max);
    let score_max = if score_max.is_finite() {
        score_max
    } else {
        0.0
    };
    let training_frames = frames.len();
    let conformal = if holdout.is_empty() {
        notes.push("no held-out episodes: only the maximum thresholds are calibrated".into());
        None
    } else {
        let held = score(holdout, thresholds.clone())?;
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

/// Per-cell statistics of the scene residual from the training frames' cell maps (all of
/// one grid); `None`, with a note, when there are none or too few.
fn fit_scene(frames: &[&FrameScore], notes: &mut Vec<String>) -> Option<CellStats> {
    let with_cells: Vec<&FrameScore> = frames
        .iter()
        .copied()
        .filter(|f| f.scene_cells.is_some())
        .collect();
    let first = with_cells.first()?;
    let (columns, rows) = first.scene_grid;
    let maps: Vec<&[f32]> = with_cells
        .iter()
        .filter(|f| f.scene_grid == (columns, rows))
        .filter_map(|f| f.scene_cells.as_deref())
        .collect();
    match CellStats::fit(columns, rows, &maps) {
        Ok(stats) => Some(stats),
        Err(e) => {
            notes.push(format!(
                "no per-cell scene statistics ({e}): e_r is scored from raw residuals"
            ));
            None
        }
    }
}

fn stem(p: &Path) -> String {
    p.file_stem().map_or_else(
        || p.display().to_string(),
        |s| s.to_string_lossy().into_owned(),
    )
}
