//! `vamos::eval` against scikit-learn and SciPy: reference values from
//! `tests/fixtures/eval/make_reference.py` (committed as `reference.json`).
//!
//! Tolerance 1e-12 for the metrics: both sides compute the same sums of the same
//! correctly rounded quotients; only the summation order differs (NumPy sums pairwise),
//! which moves the result by a few ulps of values below 1. The incomplete beta is an
//! independent implementation (continued fraction here, Boost's in SciPy): 1e-12
//! absolute, with parameters up to 1000 (see `betainc_matches_scipy`).

use std::path::Path;

use serde::Deserialize;
use vamos::eval::{
    ScoredFrame, average_precision, conformal_threshold, evaluate, pr_curve, regularized_beta,
    roc_auc, roc_curve,
};

#[derive(Deserialize)]
struct Reference {
    versions: serde_json::Value,
    metric_cases: Vec<MetricCase>,
    betainc_cases: Vec<BetaincCase>,
    conformal_cases: Vec<ConformalCase>,
}

#[derive(Deserialize)]
struct MetricCase {
    name: String,
    scores: Vec<f64>,
    labels: Vec<bool>,
    roc_auc: f64,
    average_precision: f64,
    roc_fpr: Vec<f64>,
    roc_tpr: Vec<f64>,
    roc_thresholds: Vec<f64>,
    pr_precision: Vec<f64>,
    pr_recall: Vec<f64>,
    pr_thresholds: Vec<f64>,
}

#[derive(Deserialize)]
struct BetaincCase {
    a: f64,
    b: f64,
    x: f64,
    value: f64,
}

#[derive(Deserialize)]
struct ConformalCase {
    n: usize,
    alpha: f64,
    rank_k: usize,
    confidence: f64,
}

const TOL: f64 = 1e-12;

fn reference() -> Reference {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/eval/reference.json");
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

fn assert_close(what: &str, ours: f64, theirs: f64) {
    assert!(
        (ours - theirs).abs() <= TOL,
        "{what}: ours {ours}, reference {theirs} (diff {:e})",
        (ours - theirs).abs()
    );
}

#[test]
fn reference_covers_the_hard_cases() {
    let r = reference();
    assert!(r.versions["sklearn"].is_string());
    let names: Vec<&str> = r.metric_cases.iter().map(|c| c.name.as_str()).collect();
    for needed in [
        "ties_rounded",
        "all_equal",
        "imbalance_1pct",
        "one_positive",
    ] {
        assert!(names.contains(&needed), "{needed} missing from {names:?}");
    }
}

#[test]
fn auc_roc_and_average_precision_match_sklearn() {
    for case in reference().metric_cases {
        let auc = roc_auc(&case.scores, &case.labels).unwrap();
        assert_close(&format!("{} roc_auc", case.name), auc, case.roc_auc);
        let ap = average_precision(&case.scores, &case.labels).unwrap();
        assert_close(
            &format!("{} average_precision", case.name),
            ap,
            case.average_precision,
        );
    }
}

#[test]
fn roc_curve_matches_sklearn_point_for_point() {
    for case in reference().metric_cases {
        let points = roc_curve(&case.scores, &case.labels).unwrap();
        assert_eq!(points.len(), case.roc_fpr.len(), "{}", case.name);
        assert_eq!(points[0].threshold, f64::INFINITY);
        for (i, p) in points.iter().enumerate() {
            assert_close(&format!("{} fpr[{i}]", case.name), p.fpr, case.roc_fpr[i]);
            assert_close(&format!("{} tpr[{i}]", case.name), p.tpr, case.roc_tpr[i]);
            if i > 0 {
                assert_eq!(
                    p.threshold,
                    case.roc_thresholds[i - 1],
                    "{} thr[{i}]",
                    case.name
                );
            }
        }
    }
}

#[test]
fn pr_curve_matches_sklearn_point_for_point() {
    for case in reference().metric_cases {
        let points = pr_curve(&case.scores, &case.labels).unwrap();
        assert_eq!(points.len(), case.pr_precision.len(), "{}", case.name);
        assert_eq!(points.len(), case.pr_thresholds.len() + 1, "{}", case.name);
        for (i, p) in points.iter().enumerate() {
            let what = format!("{} pr[{i}]", case.name);
            assert_close(&what, p.precision, case.pr_precision[i]);
            assert_close(&what, p.recall, case.pr_recall[i]);
            let threshold = case.pr_thresholds.get(i).copied().unwrap_or(f64::INFINITY);
            assert_eq!(p.threshold, threshold, "{what}");
        }
    }
}

#[test]
fn nan_scores_behave_as_positive_infinity() {
    let case = reference()
        .metric_cases
        .into_iter()
        .find(|c| c.name == "continuous_balanced")
        .unwrap();
    let mut with_nan = case.scores.clone();
    let mut with_inf = case.scores.clone();
    for i in [3, 11, 40] {
        with_nan[i] = f64::NAN;
        with_inf[i] = f64::INFINITY;
    }
    assert_eq!(
        roc_auc(&with_nan, &case.labels),
        roc_auc(&with_inf, &case.labels)
    );
    assert_eq!(
        average_precision(&with_nan, &case.labels),
        average_precision(&with_inf, &case.labels)
    );
    assert_ne!(
        roc_auc(&with_nan, &case.labels),
        roc_auc(&case.scores, &case.labels)
    );
}

#[test]
fn betainc_matches_scipy() {
    let cases = reference().betainc_cases;
    assert!(cases.len() > 100);
    let mut worst = 0.0f64;
    for c in cases {
        let ours = regularized_beta(c.a, c.b, c.x);
        let diff = (ours - c.value).abs();
        worst = worst.max(diff);
        assert!(
            diff <= TOL,
            "I_{}({}, {}): ours {ours}, scipy {} (diff {diff:e})",
            c.x,
            c.a,
            c.b,
            c.value
        );
    }
    eprintln!("betainc: worst absolute difference to SciPy {worst:e}");
}

#[test]
fn conformal_ranks_and_confidence_match_exact_arithmetic_and_scipy() {
    for c in reference().conformal_cases {
        // Maxima 1..n: the k-th smallest is k.
        let maxima: Vec<f64> = (1..=c.n).map(|i| i as f64).rev().collect();
        let t = conformal_threshold(&maxima, c.alpha).unwrap();
        assert_eq!(t.rank_k, c.rank_k, "n {} alpha {}", c.n, c.alpha);
        assert_eq!(t.order_statistic, c.rank_k as f64);
        assert_close(
            &format!("confidence n {} alpha {}", c.n, c.alpha),
            t.confidence,
            c.confidence,
        );
        let expected_rate = (c.n - c.rank_k) as f64 / c.n as f64;
        assert_eq!(t.calibration_false_alarm_rate, expected_rate);
    }
}

#[test]
fn evaluate_pools_frames_across_episodes_like_sklearn() {
    // Cut the pooled case into 50 episodes of 100 frames at 10 Hz: the report's AUCs are
    // the pooled ones (no per-episode normalisation), whatever the episode split.
    let case = reference()
        .metric_cases
        .into_iter()
        .find(|c| c.name == "pooled_5k_ties")
        .unwrap();
    let frames: Vec<ScoredFrame> = case
        .scores
        .iter()
        .zip(&case.labels)
        .enumerate()
        .map(|(i, (&score, &anomalous))| ScoredFrame {
            episode: format!("ep{:02}", i / 100),
            stamp_ns: (i % 100) as i64 * 100_000_000,
            score,
            anomalous,
            anomaly_type: Some(if i / 100 % 2 == 0 { "even" } else { "odd" }.to_string()),
            warming_up: i % 100 < 9,
        })
        .collect();
    let report = evaluate(&frames, 0.1);
    assert_eq!(report.frames, 5000);
    assert_eq!(report.episodes, 50);
    assert_eq!(
        report.anomalous_frames,
        case.labels.iter().filter(|&&l| l).count()
    );
    assert_close("pooled auc_roc", report.auc_roc.unwrap(), case.roc_auc);
    assert_close(
        "pooled auc_pr",
        report.auc_pr.unwrap(),
        case.average_precision,
    );
    assert_eq!(report.per_type.len(), 2);
}
