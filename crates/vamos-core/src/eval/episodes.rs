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
mod tests {
    use super::*;

    const S: i64 = 1_000_000_000;

    fn frame(
        episode: &str,
        stamp_ns: i64,
        score: f64,
        anomalous: bool,
        kind: Option<&str>,
    ) -> ScoredFrame {
        ScoredFrame {
            episode: episode.to_string(),
            stamp_ns,
            score,
            anomalous,
            anomaly_type: kind.map(str::to_string),
            warming_up: stamp_ns == 0,
        }
    }

    /// Seven episodes whose figures at threshold 0.5 are worked out by hand below.
    fn episodes() -> Vec<ScoredFrame> {
        let c = Some("collision");
        let mut frames = vec![
            // a: nominal, alarm at 1 s -> false alarm.
            frame("a", 0, 0.1, false, None),
            frame("a", S, 0.6, false, None),
            frame("a", 2 * S, 0.2, false, None),
            // b: nominal, quiet.
            frame("b", 0, 0.1, false, None),
            frame("b", S, 0.2, false, None),
            frame("b", 2 * S, 0.3, false, None),
            // c: nominal, a NaN frame alarms -> false alarm.
            frame("c", 0, 0.1, false, None),
            frame("c", S, f64::NAN, false, None),
            // d: collision, onset 2 s, first alarm at/after onset 4 s -> delay 2 s.
            frame("d", 0, 0.1, false, c),
            frame("d", S, 0.2, false, c),
            frame("d", 2 * S, 0.3, true, c),
            frame("d", 3 * S, 0.4, true, c),
            frame("d", 4 * S, 0.7, false, c),
            frame("d", 5 * S, 0.1, false, c),
            // e: collision, alarm before onset (0 s), onset 1 s, alarm 1.5 s -> 0.5 s.
            frame("e", 0, 0.9, false, c),
            frame("e", S / 2, 0.1, false, c),
            frame("e", S, 0.2, true, c),
            frame("e", 3 * S / 2, 0.55, true, c),
            // f: slip, never alarms -> missed.
            frame("f", 0, 0.1, false, Some("slip")),
            frame("f", S, 0.3, true, Some("slip")),
            frame("f", 2 * S, 0.2, true, Some("slip")),
            // g: untyped, alarm exactly at the threshold at onset -> delay 0.
            frame("g", 0, 0.2, false, None),
            frame("g", S, 0.5, true, None),
        ];
        // Input order must not matter.
        frames.reverse();
        frames
    }

    #[test]
    fn hand_worked_episode_figures() {
        let frames = episodes();
        assert_eq!(episode_false_alarm_rate(&frames, 0.5), Some(2.0 / 3.0));
        assert_eq!(pre_onset_false_alarm_rate(&frames, 0.5), Some(0.25));
        let outcomes = episode_outcomes(&frames, 0.5);
        let names: Vec<&str> = outcomes.iter().map(|o| o.episode.as_str()).collect();
        assert_eq!(names, ["a", "b", "c", "d", "e", "f", "g"]);
        let delays: Vec<Option<f64>> = outcomes.iter().map(|o| o.detection_delay_s).collect();
        assert_eq!(
            delays,
            [None, None, None, Some(2.0), Some(0.5), None, Some(0.0)]
        );
        assert_eq!(outcomes[3].onset_ns, Some(2 * S));
        assert_eq!(outcomes[4].first_alarm_ns, Some(0));
        assert_eq!(outcomes[2].max_score, f64::INFINITY);
        assert_eq!(outcomes[6].anomaly_type.as_deref(), Some(UNTYPED_ANOMALY));

        let r = evaluate(&frames, 0.5);
        assert_eq!((r.frames, r.anomalous_frames), (23, 7));
        assert_eq!((r.episodes, r.anomalous_episodes), (7, 4));
        assert_eq!(r.episode_false_alarm_rate, Some(2.0 / 3.0));
        assert_eq!(r.pre_onset_false_alarm_rate, Some(0.25));
        assert_eq!(r.detection_rate, Some(0.75));
        // Delays {2, 0.5, 0}: median 0.5.
        assert_eq!(r.median_detection_delay_s, Some(0.5));
        // d's alarm (4 s) comes 1 s after its last anomalous frame (3 s): late. e and g
        // alarm inside their intervals; f is missed.
        let timely: Vec<bool> = outcomes.iter().map(|o| o.timely).collect();
        assert_eq!(timely, [false, false, false, false, true, false, true]);
        assert_eq!(outcomes[3].end_ns, Some(3 * S));
        assert_eq!(r.timely_detection_rate, Some(0.5));
        assert_eq!(r.alarm_tolerance_s, ALARM_TOLERANCE_S);
        assert_eq!(r.threshold, 0.5);

        let keys: Vec<&str> = r.per_type.keys().map(String::as_str).collect();
        assert_eq!(keys, ["collision", "slip", UNTYPED_ANOMALY]);
        let collision = &r.per_type["collision"];
        // d (6) + e (4) + nominal a, b, c (8) frames; 4 anomalous.
        assert_eq!(
            (
                collision.frames,
                collision.anomalous_frames,
                collision.episodes
            ),
            (18, 4, 2)
        );
        assert_eq!(collision.detection_rate, Some(1.0));
        assert_eq!(collision.median_detection_delay_s, Some(1.25));
        assert_eq!(collision.timely_detection_rate, Some(0.5));
        let slip = &r.per_type["slip"];
        assert_eq!(
            (slip.frames, slip.episodes, slip.detection_rate),
            (11, 1, Some(0.0))
        );
        assert_eq!(slip.median_detection_delay_s, None);

        // Per-type AUC pools exactly those frames.
        let pool: Vec<&ScoredFrame> = frames
            .iter()
            .filter(|f| ["a", "b", "c", "f"].contains(&f.episode.as_str()))
            .collect();
        let scores: Vec<f64> = pool.iter().map(|f| f.score).collect();
        let labels: Vec<bool> = pool.iter().map(|f| f.anomalous).collect();
        assert_eq!(slip.auc_roc, roc_auc(&scores, &labels));
        assert_eq!(slip.auc_pr, average_precision(&scores, &labels));
        // The per-type ROC curves select the same frames.
        // (Bit patterns, since the pool holds a NaN score.)
        let by_type = frames_by_type(&frames);
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&by_type["slip"].0), bits(&scores));
        assert_eq!(by_type["slip"].1, labels);
        let keys: Vec<&str> = by_type.keys().map(String::as_str).collect();
        assert_eq!(keys, ["collision", "slip", UNTYPED_ANOMALY]);
        // Slip frames 0.3 and 0.2 (anomalous) against 9 negatives: 0.1 x4, 0.2 x2, 0.3,
        // 0.6, NaN (= inf). By hand 0.3 beats 6 and ties 1 (6.5), 0.2 beats 4 and ties 2
        // (5): AUC = 11.5 / 18.
        assert!((slip.auc_roc.unwrap() - 11.5 / 18.0).abs() < 1e-15);
    }

    #[test]
    fn threshold_moves_the_figures() {
        let frames = episodes();
        // At 0.95 only the NaN frame alarms: c is a false alarm, nothing is detected.
        let r = evaluate(&frames, 0.95);
        assert_eq!(r.episode_false_alarm_rate, Some(1.0 / 3.0));
        assert_eq!(r.pre_onset_false_alarm_rate, Some(0.0));
        assert_eq!(r.detection_rate, Some(0.0));
        assert_eq!(r.median_detection_delay_s, None);
        // At 0: everything alarms, delays are all 0, every nominal episode false-alarms.
        let r = evaluate(&frames, 0.0);
        assert_eq!(r.episode_false_alarm_rate, Some(1.0));
        assert_eq!(r.pre_onset_false_alarm_rate, Some(1.0));
        assert_eq!(r.median_detection_delay_s, Some(0.0));
    }

    #[test]
    fn empty_and_one_sided_inputs() {
        let r = evaluate(&[], 0.5);
        assert_eq!((r.frames, r.episodes), (0, 0));
        assert_eq!(
            (r.auc_roc, r.episode_false_alarm_rate, r.detection_rate),
            (None, None, None)
        );
        let nominal_only: Vec<ScoredFrame> = episodes()
            .into_iter()
            .filter(|f| f.episode.as_str() < "d")
            .collect();
        let r = evaluate(&nominal_only, 0.5);
        assert_eq!(r.auc_roc, None);
        assert_eq!(r.pre_onset_false_alarm_rate, None);
        assert!(r.per_type.is_empty());
    }

    #[test]
    fn json_field_names_are_the_contract() {
        let r = evaluate(&episodes(), 0.5);
        let value = serde_json::to_value(&r).unwrap();
        let mut keys: Vec<&str> = value
            .as_object()
            .unwrap()
            .keys()
            .map(String::as_str)
            .collect();
        keys.sort_unstable();
        assert_eq!(
            keys,
            [
                "alarm_tolerance_s",
                "anomalous_episodes",
                "anomalous_frames",
                "auc_pr",
                "auc_roc",
                "detection_rate",
                "episode_false_alarm_rate",
                "episodes",
                "frames",
                "median_detection_delay_s",
                "per_type",
                "pre_onset_false_alarm_rate",
                "threshold",
                "timely_detection_rate",
            ]
        );
        let mut type_keys: Vec<&str> = value["per_type"]["slip"]
            .as_object()
            .unwrap()
            .keys()
            .map(String::as_str)
            .collect();
        type_keys.sort_unstable();
        assert_eq!(
            type_keys,
            [
                "anomalous_frames",
                "auc_pr",
                "auc_roc",
                "detection_rate",
                "episodes",
                "frames",
                "median_detection_delay_s",
                "timely_detection_rate",
            ]
        );
        let back: EvalReport = serde_json::from_value(value).unwrap();
        assert_eq!(back, r);
    }
}
