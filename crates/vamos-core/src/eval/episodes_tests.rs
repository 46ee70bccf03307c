//! Episode-level evaluation: hand-worked figures, the threshold's effect, empty and
//! one-sided inputs, the JSON field names.

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
