//! Episode-level figures at a threshold, and the evaluation report.
//!
//! Definitions (a frame alarms when `score >= threshold`, NaN scores always alarm):
//! - An episode is the set of frames sharing an `episode` name, taken in stamp order. It
//!   is anomalous when at least one of its frames is labelled anomalous; its onset is the
//!   stamp of its first anomalous frame. Other episodes are nominal.
//! - Episode false-alarm rate: share of nominal episodes with at least one alarm.
//! - Pre-onset false-alarm rate: share of anomalous episodes with an alarm strictly
//!   before the onset.
//! - Detection delay of an anomalous episode: stamp of the first alarm at or after the
//!   onset minus the onset, in seconds; missed when there is none. (An alarm after the
//!   anomalous interval has ended still counts: the episode was flagged.)
//! - Detection rate: detected / anomalous episodes; median delay over detected episodes.
//! - Timely detection: an alarm at or after the onset and no later than the last
//!   anomalous frame plus [`ALARM_TOLERANCE_S`]; a detected episode without one was found
//!   late (an alarm 6 s after a 0.3 s fall is not what an operator needs).
//!
//! Frames that are warming up are evaluated like any other: they carry a score (from e_c
//! and e_b only), and the detector's behaviour during warm-up is part of what is measured.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use super::ScoredFrame;
use super::metrics::{average_precision, roc_auc};

/// `per_type` key for anomalous episodes whose labels name no type.
pub const UNTYPED_ANOMALY: &str = "unspecified";

/// How long after the last anomalous frame an alarm still counts as timely, seconds: a
/// few frames at the usual 10-30 Hz, for the flow of the last anomalous frame to arrive.
pub const ALARM_TOLERANCE_S: f64 = 0.5;

/// What happened in one episode at a threshold.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EpisodeOutcome {
    /// Episode name.
    pub episode: String,
    /// At least one frame is labelled anomalous.
    pub anomalous: bool,
    /// Anomaly type of an anomalous episode (its first frame in stamp order that names
    /// one; [`UNTYPED_ANOMALY`] if none does); `None` for nominal episodes.
    pub anomaly_type: Option<String>,
    /// Frames in the episode.
    pub frames: usize,
    /// Frames labelled anomalous.
    pub anomalous_frames: usize,
    /// Highest score in the episode (NaN counts as `+inf`).
    pub max_score: f64,
    /// Stamp of the first anomalous frame.
    pub onset_ns: Option<i64>,
    /// Stamp of the first alarm anywhere in the episode.
    pub first_alarm_ns: Option<i64>,
    /// Nominal episode: any alarm. Anomalous episode: an alarm strictly before onset.
    pub false_alarm: bool,
    /// Anomalous episode: seconds from onset to the first alarm at or after it; `None`
    /// when missed or nominal.
    pub detection_delay_s: Option<f64>,
    /// Stamp of the last anomalous frame.
    #[serde(default)]
    pub end_ns: Option<i64>,
    /// Anomalous episode: an alarm between the onset and the last anomalous frame plus
    /// [`ALARM_TOLERANCE_S`].
    #[serde(default)]
    pub timely: bool,
}

fn alarms(score: f64, threshold: f64) -> bool {
    score.is_nan() || score >= threshold
}

/// Per-episode outcomes at `threshold`, sorted by episode name.
pub fn episode_outcomes(frames: &[ScoredFrame], threshold: f64) -> Vec<EpisodeOutcome> {
    let mut by_episode: BTreeMap<&str, Vec<&ScoredFrame>> = BTreeMap::new();
    for f in frames {
        by_episode.entry(f.episode.as_str()).or_default().push(f);
    }
    by_episode
        .into_iter()
        .map(|(name, mut episode)| {
            episode.sort_by_key(|f| f.stamp_ns);
            outcome(name, &episode, threshold)
        })
        .collect()
}

/// The outcome of one episode whose frames are sorted by stamp.
fn outcome(name: &str, frames: &[&ScoredFrame], threshold: f64) -> EpisodeOutcome {
    let onset_ns = frames.iter().find(|f| f.anomalous).map(|f| f.stamp_ns);
    let first_alarm_ns = frames
        .iter()
        .find(|f| alarms(f.score, threshold))
        .map(|f| f.stamp_ns);
    let max_score = frames
        .iter()
        .map(|f| {
            if f.score.is_nan() {
                f64::INFINITY
            } else {
                f.score
            }
        })
        .fold(f64::NEG_INFINITY, f64::max);
    let anomalous_frames = frames.iter().filter(|f| f.anomalous).count();
    let end_ns = frames
        .iter()
        .rev()
        .find(|f| f.anomalous)
        .map(|f| f.stamp_ns);
    let timely = match (onset_ns, end_ns) {
        (Some(onset), Some(end)) => {
            let until = end.saturating_add((ALARM_TOLERANCE_S * 1e9) as i64);
            frames
                .iter()
                .any(|f| (onset..=until).contains(&f.stamp_ns) && alarms(f.score, threshold))
        }
        _ => false,
    };
    let (false_alarm, detection_delay_s, anomaly_type) = match onset_ns {
        None => (first_alarm_ns.is_some(), None, None),
        Some(onset) => {
            let pre_onset = frames
                .iter()
                .any(|f| f.stamp_ns < onset && alarms(f.score, threshold));
            let delay = frames
                .iter()
                .find(|f| f.stamp_ns >= onset && alarms(f.score, threshold))
                .map(|f| f.stamp_ns.saturating_sub(onset) as f64 * 1e-9);
            let kind = frames
                .iter()
                .find_map(|f| f.anomaly_type.clone())
                .unwrap_or_else(|| UNTYPED_ANOMALY.to_string());
            (pre_onset, delay, Some(kind))
        }
    };
    EpisodeOutcome {
        episode: name.to_string(),
        anomalous: onset_ns.is_some(),
        anomaly_type,
        frames: frames.len(),
        anomalous_frames,
        max_score,
        onset_ns,
        first_alarm_ns,
        false_alarm,
        detection_delay_s,
        end_ns,
        timely,
    }
}

fn share(hits: usize, total: usize) -> Option<f64> {
    (total > 0).then(|| hits as f64 / total as f64)
}

fn median(mut values: Vec<f64>) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    values.sort_by(f64::total_cmp);
    let mid = values.len() / 2;
    Some(if values.len() % 2 == 1 {
        values[mid]
    } else {
        0.5 * (values[mid - 1] + values[mid])
    })
}

/// Share of nominal episodes (no anomalous frame) with some frame scoring `>= threshold`;
/// `None` without nominal episodes.
pub fn episode_false_alarm_rate(frames: &[ScoredFrame], threshold: f64) -> Option<f64> {
    let outcomes = episode_outcomes(frames, threshold);
    nominal_false_alarm_rate(&outcomes)
}

fn nominal_false_alarm_rate(outcomes: &[EpisodeOutcome]) -> Option<f64> {
    let nominal: Vec<_> = outcomes.iter().filter(|o| !o.anomalous).collect();
    share(
        nominal.iter().filter(|o| o.false_alarm).count(),
        nominal.len(),
    )
}

/// Share of anomalous episodes with an alarm strictly before their first anomalous
/// frame; `None` without anomalous episodes.
pub fn pre_onset_false_alarm_rate(frames: &[ScoredFrame], threshold: f64) -> Option<f64> {
    let outcomes = episode_outcomes(frames, threshold);
    let anomalous: Vec<_> = outcomes.iter().filter(|o| o.anomalous).collect();
    share(
        anomalous.iter().filter(|o| o.false_alarm).count(),
        anomalous.len(),
    )
}

/// Detection over anomalous episodes: rate, median delay and timely rate.
struct Detection {
    rate: Option<f64>,
    median_delay_s: Option<f64>,
    timely_rate: Option<f64>,
}

fn detection<'a>(anomalous: impl Iterator<Item = &'a EpisodeOutcome>) -> Detection {
    let mut total = 0;
    let mut timely = 0;
    let mut delays = Vec::new();
    for o in anomalous {
        total += 1;
        timely += usize::from(o.timely);
        if let Some(d) = o.detection_delay_s {
            delays.push(d);
        }
    }
    Detection {
        rate: share(delays.len(), total),
        median_delay_s: median(delays),
        timely_rate: share(timely, total),
    }
}

/// Figures for one anomaly type.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TypeReport {
    /// Frame-level AUC-ROC over this type's episodes plus all nominal episodes.
    pub auc_roc: Option<f64>,
    /// Frame-level average precision over the same frames.
    pub auc_pr: Option<f64>,
    /// Frames pooled: this type's episodes plus all nominal episodes.
    pub frames: usize,
    /// Anomalous frames among them.
    pub anomalous_frames: usize,
    /// Anomalous episodes of this type (nominal episodes not counted).
    pub episodes: usize,
    /// Detected / episodes of this type.
    pub detection_rate: Option<f64>,
    /// Median detection delay over this type's detected episodes, seconds.
    pub median_detection_delay_s: Option<f64>,
    /// Episodes of this type with a timely alarm / episodes.
    #[serde(default)]
    pub timely_detection_rate: Option<f64>,
}

/// The evaluation figures at one threshold (JSON field names are part of the CLI's
/// contract).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EvalReport {
    /// Pooled frame-level AUC-ROC (`None` when a class is absent).
    pub auc_roc: Option<f64>,
    /// Pooled frame-level average precision (`None` when a class is absent).
    pub auc_pr: Option<f64>,
    /// Frames evaluated (warming-up frames included).
    pub frames: usize,
    /// Frames labelled anomalous.
    pub anomalous_frames: usize,
    /// Episodes.
    pub episodes: usize,
    /// Episodes with at least one anomalous frame.
    pub anomalous_episodes: usize,
    /// The threshold the episode figures use (alarm: `score >= threshold`).
    pub threshold: f64,
    /// Share of nominal episodes with an alarm (`None` without nominal episodes).
    pub episode_false_alarm_rate: Option<f64>,
    /// Share of anomalous episodes with an alarm before onset.
    pub pre_onset_false_alarm_rate: Option<f64>,
    /// Detected / anomalous episodes.
    pub detection_rate: Option<f64>,
    /// Median seconds from onset to first alarm over detected episodes.
    pub median_detection_delay_s: Option<f64>,
    /// Anomalous episodes with an alarm between onset and the last anomalous frame plus
    /// `alarm_tolerance_s` / anomalous episodes (the rest of the detected ones were late).
    #[serde(default)]
    pub timely_detection_rate: Option<f64>,
    /// The tolerance after the last anomalous frame, seconds ([`ALARM_TOLERANCE_S`]).
    #[serde(default)]
    pub alarm_tolerance_s: f64,
    /// The same per anomaly type: each type's episodes pooled with all nominal
    /// episodes (untyped anomalies under [`UNTYPED_ANOMALY`]).
    pub per_type: BTreeMap<String, TypeReport>,
}

/// Per anomaly type, the scores and labels of that type's episodes pooled with every
/// nominal episode's frames (the selection behind [`EvalReport::per_type`] and the per-type
/// ROC curves), keyed by type in name order.
pub fn frames_by_type(frames: &[ScoredFrame]) -> BTreeMap<String, (Vec<f64>, Vec<bool>)> {
    // Episode name -> its type (an episode with an anomalous frame) or None (nominal), as
    // in [`episode_outcomes`].
    let mut kind_of: BTreeMap<&str, Option<String>> = BTreeMap::new();
    for f in frames {
        let kind = kind_of.entry(f.episode.as_str()).or_default();
        if f.anomalous && kind.is_none() {
            *kind = Some(
                frames
                    .iter()
                    .filter(|g| g.episode == f.episode)
                    .find_map(|g| g.anomaly_type.clone())
                    .unwrap_or_else(|| UNTYPED_ANOMALY.to_string()),
            );
        }
    }
    let mut by_type: BTreeMap<String, (Vec<f64>, Vec<bool>)> = kind_of
        .values()
        .flatten()
        .map(|k| (k.clone(), (Vec::new(), Vec::new())))
        .collect();
    for f in frames {
        let episode_kind = kind_of.get(f.episode.as_str()).and_then(Option::as_deref);
        for (kind, (scores, labels)) in by_type.iter_mut() {
            if episode_kind.is_none_or(|k| k == kind) {
                scores.push(f.score);
                labels.push(f.anomalous);
            }
        }
    }
    by_type
}

/// Evaluate scored frames at `threshold`: pooled frame-level AUCs, episode false alarms,
/// detection rate and delay, and the same per anomaly type (see the module doc).
pub fn evaluate(frames: &[ScoredFrame], threshold: f64) -> EvalReport {
    let outcomes = episode_outcomes(frames, threshold);
    let scores: Vec<f64> = frames.iter().map(|f| f.score).collect();
    let labels: Vec<bool> = frames.iter().map(|f| f.anomalous).collect();
    let anomalous: Vec<&EpisodeOutcome> = outcomes.iter().filter(|o| o.anomalous).collect();
    let overall = detection(anomalous.iter().copied());

    let mut per_type = BTreeMap::new();
    for (kind, (type_scores, type_labels)) in frames_by_type(frames) {
        let kind = kind.as_str();
        let of_kind = || {
            anomalous
                .iter()
                .copied()
                .filter(move |o| o.anomaly_type.as_deref() == Some(kind))
        };
        let found = detection(of_kind());
        per_type.insert(
            kind.to_string(),
            TypeReport {
                auc_roc: roc_auc(&type_scores, &type_labels),
                auc_pr: average_precision(&type_scores, &type_labels),
                frames: type_scores.len(),
                anomalous_frames: type_labels.iter().filter(|&&l| l).count(),
                episodes: of_kind().count(),
                detection_rate: found.rate,
                median_detection_delay_s: found.median_delay_s,
                timely_detection_rate: found.timely_rate,
            },
        );
    }

    EvalReport {
        auc_roc: roc_auc(&scores, &labels),
        auc_pr: average_precision(&scores, &labels),
        frames: frames.len(),
        anomalous_frames: labels.iter().filter(|&&l| l).count(),
        episodes: outcomes.len(),
        anomalous_episodes: anomalous.len(),
        threshold,
        episode_false_alarm_rate: nominal_false_alarm_rate(&outcomes),
        pre_onset_false_alarm_rate: share(
            anomalous.iter().filter(|o| o.false_alarm).count(),
            anomalous.len(),
        ),
        detection_rate: overall.rate,
        median_detection_delay_s: overall.median_delay_s,
        timely_detection_rate: overall.timely_rate,
        alarm_tolerance_s: ALARM_TOLERANCE_S,
        per_type,
    }
}

#[cfg(test)]
#[path = "episodes_tests.rs"]
mod tests;
