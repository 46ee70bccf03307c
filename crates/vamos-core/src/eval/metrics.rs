//! Frame-level ranking metrics with scikit-learn's exact definitions.
//!
//! - [`roc_curve`] / [`roc_auc`]: `sklearn.metrics.roc_curve(drop_intermediate=False)`
//!   and `roc_auc_score`: one point per distinct score (ties move both rates at once, so
//!   the trapezoid between two thresholds credits a tie with half), plus the origin with
//!   threshold `+inf`.
//! - [`pr_curve`] / [`average_precision`]: `precision_recall_curve` and
//!   `average_precision_score` = sum over distinct thresholds of `(R_n - R_{n-1}) P_n`,
//!   without interpolation.
//!
//! Scores are "higher = more anomalous" and a frame is flagged when `score >= threshold`.
//! NaN scores count as `+inf` (module policy: a broken frame must not hide). `-0.0` and
//! `0.0` are the same score, as in NumPy. Where scikit-learn warns and returns NaN or a
//! degenerate value because one class is absent, these functions return `None`; they
//! also return `None` when `scores` and `labels` differ in length.

use std::cmp::Ordering;

use serde::{Deserialize, Serialize};

/// One point of a ROC curve.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RocPoint {
    /// Frames with `score >= threshold` are flagged; the first point has `+inf`.
    pub threshold: f64,
    /// False-positive rate at this threshold.
    pub fpr: f64,
    /// True-positive rate (recall) at this threshold.
    pub tpr: f64,
}

/// One point of a precision-recall curve.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PrPoint {
    /// Frames with `score >= threshold` are flagged. Points run from the lowest threshold
    /// to the highest, as in scikit-learn; the final point (precision 1, recall 0) has no
    /// threshold there and `+inf` here.
    pub threshold: f64,
    /// Precision at this threshold.
    pub precision: f64,
    /// Recall at this threshold.
    pub recall: f64,
}

/// The score the ranking uses: NaN becomes `+inf`, `-0.0` becomes `0.0`.
fn rank_key(score: f64) -> f64 {
    if score.is_nan() {
        f64::INFINITY
    } else {
        // -0.0 + 0.0 == +0.0 under round-to-nearest.
        score + 0.0
    }
}

/// Cumulative counts at each distinct threshold, highest threshold first
/// (scikit-learn's `_binary_clf_curve`).
struct ClfCurve {
    thresholds: Vec<f64>,
    true_positives: Vec<u64>,
    false_positives: Vec<u64>,
}

impl ClfCurve {
    /// `None` when the lengths differ or either class is absent.
    fn new(scores: &[f64], labels: &[bool]) -> Option<Self> {
        if scores.len() != labels.len() {
            return None;
        }
        let keys: Vec<f64> = scores.iter().map(|&s| rank_key(s)).collect();
        let mut order: Vec<usize> = (0..keys.len()).collect();
        order.sort_by(|&a, &b| keys[b].partial_cmp(&keys[a]).unwrap_or(Ordering::Equal));
        let mut curve = ClfCurve {
            thresholds: Vec::new(),
            true_positives: Vec::new(),
            false_positives: Vec::new(),
        };
        let (mut tp, mut fp) = (0u64, 0u64);
        for (pos, &i) in order.iter().enumerate() {
            if labels[i] {
                tp += 1;
            } else {
                fp += 1;
            }
            let last_of_run = order.get(pos + 1).is_none_or(|&next| keys[next] != keys[i]);
            if last_of_run {
                curve.thresholds.push(keys[i]);
                curve.true_positives.push(tp);
                curve.false_positives.push(fp);
            }
        }
        (tp > 0 && fp > 0).then_some(curve)
    }

    fn totals(&self) -> (f64, f64) {
        // Invariant: `new` returns a curve only with at least one point.
        let last = self.thresholds.len() - 1;
        (
            self.true_positives[last] as f64,
            self.false_positives[last] as f64,
        )
    }
}

/// The ROC curve, from the origin (threshold `+inf`) to (1, 1): one point per distinct
/// score, highest first (scikit-learn's `roc_curve` with `drop_intermediate=False`).
/// `None` when a class is absent or the lengths differ.
pub fn roc_curve(scores: &[f64], labels: &[bool]) -> Option<Vec<RocPoint>> {
    let curve = ClfCurve::new(scores, labels)?;
    let (positives, negatives) = curve.totals();
    let mut points = Vec::with_capacity(curve.thresholds.len() + 1);
    points.push(RocPoint {
        threshold: f64::INFINITY,
        fpr: 0.0,
        tpr: 0.0,
    });
    for i in 0..curve.thresholds.len() {
        points.push(RocPoint {
            threshold: curve.thresholds[i],
            fpr: curve.false_positives[i] as f64 / negatives,
            tpr: curve.true_positives[i] as f64 / positives,
        });
    }
    Some(points)
}

/// Area under the ROC curve (scikit-learn's `roc_auc_score`): the trapezoid over the
/// points of [`roc_curve`]. `None` when a class is absent or the lengths differ.
pub fn roc_auc(scores: &[f64], labels: &[bool]) -> Option<f64> {
    let points = roc_curve(scores, labels)?;
    Some(
        points
            .windows(2)
            .map(|w| (w[1].fpr - w[0].fpr) * (w[1].tpr + w[0].tpr) / 2.0)
            .sum(),
    )
}

/// The precision-recall curve as scikit-learn's `precision_recall_curve` returns it:
/// lowest threshold first, ending with (precision 1, recall 0) at threshold `+inf`.
/// `None` when a class is absent or the lengths differ.
pub fn pr_curve(scores: &[f64], labels: &[bool]) -> Option<Vec<PrPoint>> {
    let curve = ClfCurve::new(scores, labels)?;
    let (positives, _) = curve.totals();
    let mut points = Vec::with_capacity(curve.thresholds.len() + 1);
    for i in (0..curve.thresholds.len()).rev() {
        let tp = curve.true_positives[i] as f64;
        let flagged = tp + curve.false_positives[i] as f64;
        points.push(PrPoint {
            threshold: curve.thresholds[i],
            precision: tp / flagged,
            recall: tp / positives,
        });
    }
    points.push(PrPoint {
        threshold: f64::INFINITY,
        precision: 1.0,
        recall: 0.0,
    });
    Some(points)
}

/// Average precision (scikit-learn's `average_precision_score`): the sum over distinct
/// thresholds of `(R_n - R_{n-1}) P_n`, no interpolation. `None` when a class is absent
/// (scikit-learn returns 0 without positives and 1 without negatives) or the lengths
/// differ.
pub fn average_precision(scores: &[f64], labels: &[bool]) -> Option<f64> {
    let points = pr_curve(scores, labels)?;
    // Same expression as scikit-learn: -sum(diff(recall) * precision[:-1]).
    let sum: f64 = points
        .windows(2)
        .map(|w| (w[1].recall - w[0].recall) * w[0].precision)
        .sum();
    Some(-sum)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hand_worked_auc_with_a_tie() {
        // Scores 0.9(+) 0.5(+) 0.5(-) 0.1(-): ROC points (0,0) (0,.5) (.5,1) (1,1);
        // area = 0.5 * (0.5 + 1) / 2 + 0.5 * 1 = 0.875 (the tie is credited half).
        let scores = [0.9, 0.5, 0.5, 0.1];
        let labels = [true, true, false, false];
        assert_eq!(roc_auc(&scores, &labels), Some(0.875));
        // AP: thresholds 0.9 (P=1, R=.5), 0.5 (P=2/3, R=1): 0.5 * 1 + 0.5 * 2/3.
        let ap = average_precision(&scores, &labels).unwrap();
        assert!((ap - (0.5 + 1.0 / 3.0)).abs() < 1e-15, "{ap}");
    }

    #[test]
    fn nan_scores_rank_as_infinite() {
        // The NaN frame is a negative: it outranks everything, like +inf would.
        let with_nan = [f64::NAN, 0.9, 0.2, 0.1];
        let with_inf = [f64::INFINITY, 0.9, 0.2, 0.1];
        let labels = [false, true, true, false];
        assert_eq!(roc_auc(&with_nan, &labels), roc_auc(&with_inf, &labels));
        assert_eq!(roc_auc(&with_nan, &labels), Some(0.5));
        let curve = roc_curve(&with_nan, &labels).unwrap();
        assert_eq!(curve[1].threshold, f64::INFINITY);
        assert_eq!((curve[1].fpr, curve[1].tpr), (0.5, 0.0));
    }

    #[test]
    fn one_class_or_mismatched_lengths_give_none() {
        assert_eq!(roc_auc(&[0.1, 0.2], &[true, true]), None);
        assert_eq!(average_precision(&[0.1, 0.2], &[false, false]), None);
        assert_eq!(roc_auc(&[0.1, 0.2], &[true]), None);
        assert!(pr_curve(&[], &[]).is_none());
    }
}
