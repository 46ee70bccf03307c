//! The calibration of a profile from nominal episodes (`vamos calibrate` and the service's
//! calibration jobs run this one function; they differ only in how episodes are scored).
//!
//! 1. The training episodes are scored without thresholds; `e_c_thres` and `e_b_thres`
//!    are the maxima of `e_c` and `e_b` over them (the paper). With `learn_depth`, the
//!    static scene's depth is first learned from that pass ([`super::depth`]) and the
//!    training episodes are scored again with it.
//! 2. Each detector fits its statistics ([`super::detectors`]): the scene residual's per-cell statistics are fitted on the training frames' cell
//!    maps, their `e_r` pooled again with them (and so the flow predictor's error per cell
//!    and `e_o`, with `flow_pooling = "cells"`), and each detector's nominal scale
//!    (median, 99th percentile) fitted on the training frames (calibrated fusion).
//!    The kinematic novelty's nominal states are the training frames' robot states; each
//!    training frame's `e_k` is its distance to the *other* episodes' states (its own
//!    would make it zero), and its scale is fitted on those.
//! 3. With all that, the largest fused score over the training frames is the `max` alarm
//!    threshold.
//! 4. The held-out nominal episodes are scored with the thresholds; the split-conformal
//!    threshold on their per-episode maximum fused score bounds the episode-level false-
//!    alarm probability by `alpha` ([`crate::eval::conformal_threshold`]).

use super::PipelineConfig;
use super::detectors::{flow, kinematics, scene};
use super::offline::EpisodeScores;
use super::profile::Calibration;
use super::scorer::{FrameScore, phase_s};
use crate::eval::{
    Detector, DetectorValues, EvalError, PerDetector, TRIGGER_BASE, Thresholds, Window,
    conformal_episodes_needed, conformal_threshold, fit_scales, fuse_frame, max_threshold,
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
    let fusion = pipeline
        .fusion
        .resolve(&Thresholds::default(), model_sha256.is_some());
    let mut train = score(training, Thresholds::default())?;
    let mut notes = Vec::new();
    let depth = pipeline
        .camera_motion
        .learn_depth
        .then(|| scene::learn_depth(&train, pipeline, &mut notes))
        .flatten();
    if let Some(depth) = &depth {
        // The training frames again, the static scene placed at the learned depth.
        train = score(
            training,
            Thresholds {
                depth: Some(depth.clone()),
                ..Thresholds::default()
            },
        )?;
    }
    let frames: Vec<&FrameScore> = train.iter().flat_map(|e| &e.frames).collect();
    // Each frame's phase: seconds since its episode's first frame.
    let phases: Vec<f64> = train
        .iter()
        .flat_map(|e| {
            let first = e.frames.first().map_or(0, |f| f.stamp_ns);
            e.frames.iter().map(move |f| phase_s(first, f.stamp_ns))
        })
        .collect();
    // Each training frame's detector values as then scored: e_c and e_b as they are, e_r
    // and e_o pooled again with the fitted cell statistics, e_k against the other
    // episodes' states.
    let (scene, e_r) = scene::fit(&frames, &phases, &pipeline.residual, &mut notes);
    let (flow, e_o) = flow::fit(&frames, &phases, &pipeline.residual, &mut notes);
    let (kinematics, e_k) = kinematics::fit(&train, &pipeline.kinematics, &mut notes);
    let mut training: PerDetector<Vec<Option<f64>>> =
        PerDetector::from_fn(|d| frames.iter().map(|f| f.values[d]).collect());
    training[Detector::Scene] = e_r;
    training[Detector::Flow] = e_o;
    training[Detector::Kinematics] = e_k;
    let finite = training.map(|_, v| v.iter().flatten().copied().collect::<Vec<f64>>());
    let thresholds = Thresholds {
        e_c: max_threshold(&finite[Detector::Camera]),
        e_b: max_threshold(&finite[Detector::Body]),
        scales: Some(fit_scales(&finite)),
        scene,
        kinematics,
        flow,
        fusion: Some(fusion),
        depth,
    };
    // The training frames' fused scores as the scorer gives them (windowed per episode).
    let mut window = Window::new(pipeline.temporal_window);
    let mut frame = 0;
    let mut score_max = f64::NEG_INFINITY;
    for episode in &train {
        window.clear();
        for _ in &episode.frames {
            let values: DetectorValues = training.map(|_, v| v[frame]);
            frame += 1;
            score_max = score_max.max(window.push(fuse_frame(&values, &thresholds, fusion)).score);
        }
    }
    let score_max = if score_max.is_finite() {
        score_max
    } else {
        0.0
    };
    let training_frames = frames.len();
    // Without a conformal threshold, `alarm = "conformal"` falls back to the training
    // maximum: every way there says so, with the numbers.
    let fallback =
        format!("alarms use the training maximum of the fused score ({score_max:.6}) instead");
    let conformal = if holdout.is_empty() {
        let needs = if alpha > 0.0 && alpha < 1.0 {
            format!(
                "; the conformal threshold at alpha {alpha} needs at least {} held-out \
                 nominal episodes",
                conformal_episodes_needed(alpha)
            )
        } else {
            String::new()
        };
        notes.push(format!(
            "no held-out episodes: no conformal threshold, {fallback}{needs}"
        ));
        None
    } else {
        let held = score(holdout, thresholds.clone())?;
        let maxima: Vec<f64> = held.iter().map(episode_max).collect();
        match conformal_threshold(&maxima, alpha) {
            Ok(c) => {
                if c.rank_k == c.n {
                    notes.push(format!(
                        "the conformal threshold is the largest of the {} held-out episodes' \
                         maxima (alpha {}): one unusual nominal run sets it; {} or more \
                         held-out episodes leave the largest out",
                        c.n,
                        alpha,
                        episodes_beyond_max(alpha)
                    ));
                }
                if c.threshold >= TRIGGER_BASE {
                    notes.push(format!(
                        "the conformal threshold ({:.6e}) lies above {TRIGGER_BASE:e}: held-out \
                         nominal episodes passed the training e_c/e_b maxima, so under the \
                         paper's fusion no frame below those maxima can ever alarm (e_o can \
                         never raise one); more or more varied training episodes, or \
                         fusion = \"calibrated\", avoid it",
                        c.threshold
                    ));
                }
                Some(c)
            }
            Err(EvalError::TooFewEpisodes {
                n, alpha, needed, ..
            }) => {
                notes.push(format!(
                    "no conformal threshold: {n} held-out episode{} given, the conformal \
                     threshold at alpha {alpha} needs at least {needed}; {fallback}",
                    if n == 1 { "" } else { "s" }
                ));
                None
            }
            Err(e) => {
                notes.push(format!("no conformal threshold: {e}; {fallback}"));
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

/// What [`revise`] proposes.
#[derive(Debug, Clone)]
pub struct Revision {
    /// The revised calibration (created now).
    pub calibration: Calibration,
    /// Each nominal episode: its name and largest fused score under the calibration it
    /// was scored with and under the revised one.
    pub episodes: Vec<(String, f64, f64)>,
    /// What changed and why, in words.
    pub notes: Vec<String>,
}

/// Revises `calibration` with `nominal` episodes, scored with it, that an operator judged
/// nominal (their alarms were false alarms), for a profile with `pipeline` (its fusion
/// resolved on `flow_model`):
///
/// 1. `e_c` and `e_b` thresholds are the paper's nominal maxima: where these episodes
///    reach them, they are raised just above these episodes' maxima; their robot states
///    join the kinematic novelty's nominal states, and each episode's `e_k` is measured
///    again against the old states and the other episodes' ([`learn_states`]);
/// 2. each episode's largest fused score is recomputed from its frames' detector values
///    with the revised thresholds, the same fusion and temporal window as the scorer's;
/// 3. the `max` alarm threshold (`score_max`) is raised to the largest of them; the
///    conformal threshold is recomputed, at the same alpha, over the held-out maxima the
///    calibration kept together with these episodes' (held-out nominal episodes like
///    them); a calibration that kept none has its threshold raised just above these
///    episodes' largest maximum (the guarantee then no longer holds as stated: noted).
///
/// The scene statistics and nominal scales are left as they are (training statistics).
pub fn revise(
    calibration: &Calibration,
    pipeline: &PipelineConfig,
    flow_model: bool,
    nominal: &[EpisodeScores],
) -> Revision {
    let fusion = pipeline.fusion.resolve(&calibration.thresholds, flow_model);
    let mut notes = Vec::new();
    let mut revised = calibration.clone();
    let component_max = |get: fn(&FrameScore) -> Option<f64>| {
        max_threshold(
            &nominal
                .iter()
                .flat_map(|e| e.frames.iter().filter_map(get))
                .collect::<Vec<_>>(),
        )
    };
    for (name, current, seen) in [
        (
            "e_c",
            &mut revised.thresholds.e_c,
            component_max(|f| f.values[Detector::Camera]),
        ),
        (
            "e_b",
            &mut revised.thresholds.e_b,
            component_max(|f| f.values[Detector::Body]),
        ),
    ] {
        // Just above the episodes' maximum: none of their frames fires it.
        if let (Some(t), Some(m)) = (current.as_mut(), seen.map(f64::next_up))
            && m > *t
        {
            notes.push(format!(
                "{name} threshold {t:.6} -> {m:.6} (just above the episodes' maximum)"
            ));
            *t = m;
        }
    }
    let e_k = kinematics::revise(calibration, &mut revised, nominal, &mut notes);
    let mut window = Window::new(pipeline.temporal_window);
    let episodes: Vec<(String, f64, f64)> = nominal
        .iter()
        .zip(&e_k)
        .map(|(e, e_k)| {
            window.clear();
            let after = e
                .frames
                .iter()
                .zip(e_k)
                .map(|(f, &e_k)| {
                    let mut c = f.values;
                    c[Detector::Kinematics] = e_k;
                    window
                        .push(fuse_frame(&c, &revised.thresholds, fusion))
                        .score
                })
                .fold(0.0, f64::max);
            (e.name.clone(), episode_max(e), after)
        })
        .collect();
    let largest = episodes
        .iter()
        .map(|e| e.2)
        .fold(f64::NEG_INFINITY, f64::max);
    if largest > revised.score_max {
        notes.push(format!(
            "max alarm threshold {:.6} -> {:.6}",
            revised.score_max, largest
        ));
        revised.score_max = largest;
    }
    if let Some(c) = calibration.conformal.as_ref() {
        let maxima: Vec<f64> = episodes.iter().map(|e| e.2).collect();
        if c.episode_maxima.is_empty() {
            if largest >= c.threshold {
                let mut raised = c.clone();
                raised.order_statistic = largest;
                raised.threshold = largest.next_up();
                notes.push(format!(
                    "conformal threshold {:.6} -> {:.6}: raised above these episodes, as the \
                     calibration kept no held-out maxima to recompute it from (its stated \
                     guarantee no longer holds as computed; recalibrate from episodes to \
                     restore it)",
                    c.threshold, raised.threshold
                ));
                revised.conformal = Some(raised);
            }
        } else {
            let all: Vec<f64> = c.episode_maxima.iter().copied().chain(maxima).collect();
            match conformal_threshold(&all, c.alpha) {
                Ok(new) => {
                    notes.push(format!(
                        "conformal threshold {:.6} -> {:.6} over {} held-out episodes ({} \
                         before, alpha {})",
                        c.threshold, new.threshold, new.n, c.n, c.alpha
                    ));
                    revised.conformal = Some(new);
                }
                Err(e) => notes.push(format!("conformal threshold kept: {e}")),
            }
        }
    }
    revised
        .calibration_episodes
        .extend(episodes.iter().map(|e| e.0.clone()));
    revised.created_unix_s = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    Revision {
        calibration: revised,
        episodes,
        notes,
    }
}

/// The fewest held-out episodes whose split-conformal rank `ceil((n + 1)(1 - alpha))` is
/// below `n` (the threshold is then not simply their maximum): `n >= (2 - alpha) / alpha`.
fn episodes_beyond_max(alpha: f64) -> usize {
    ((2.0 - alpha) / alpha).ceil().clamp(1.0, 1e9) as usize
}

fn stem(p: &Path) -> String {
    p.file_stem().map_or_else(
        || p.display().to_string(),
        |s| s.to_string_lossy().into_owned(),
    )
}

#[cfg(test)]
#[path = "calibration_tests.rs"]
mod tests;
