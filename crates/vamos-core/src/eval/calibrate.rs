//! Threshold calibration: the paper's max over training, and split-conformal
//! calibration of the fused-score threshold with a per-episode false-alarm budget.
//!
//! Conformal calibration. Take n held-out nominal episodes and their maximum fused
//! scores S_1..S_n. A new nominal episode raises a false alarm when its maximum reaches
//! the threshold. With k = ceil((n + 1)(1 - alpha)) and S_(k) the k-th smallest,
//! exchangeability gives P(S_new <= S_(k)) >= k / (n + 1) >= 1 - alpha, ties included.
//! Alarms fire on `score >= threshold`, so the threshold is the next float above S_(k):
//! `score >= threshold` is then exactly `score > S_(k)`, and the false-alarm probability
//! is at most 1 - k / (n + 1) <= alpha (marginal over calibration sets).
//!
//! Confidence. For one calibration set the threshold's own false-alarm rate is
//! 1 - F(S_(k)), with F the distribution of an episode maximum; F(S_(k)) is the k-th
//! order statistic of n uniforms, Beta(k, n + 1 - k). So
//! P(rate <= alpha) = P(Beta(k, n + 1 - k) >= 1 - alpha) = 1 - I_{1-alpha}(k, n + 1 - k),
//! exact for continuous scores and a lower bound with ties.

use serde::{Deserialize, Serialize};

use super::EvalError;

/// The paper's threshold: the maximum over training values, NaN ignored. `None` when
/// there is no non-NaN value (an empty training set must not silently become a
/// threshold).
pub fn max_threshold(values: &[f64]) -> Option<f64> {
    values
        .iter()
        .copied()
        .filter(|v| !v.is_nan())
        .fold(None, |best: Option<f64>, v| {
            Some(best.map_or(v, |b| b.max(v)))
        })
}

/// A conformal threshold on the fused score with its guarantees.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ConformalThreshold {
    /// Alarm when `score >= threshold`: the next float above `order_statistic`.
    pub threshold: f64,
    /// S_(k), the k-th smallest calibration episode maximum.
    pub order_statistic: f64,
    /// The per-episode false-alarm budget asked for.
    pub alpha: f64,
    /// Calibration episodes used.
    pub n: usize,
    /// The rank k = ceil((n + 1)(1 - alpha)), 1-based.
    pub rank_k: usize,
    /// Guaranteed bound on the marginal per-episode false-alarm probability: alpha.
    pub guaranteed_false_alarm_max: f64,
    /// The exact marginal bound 1 - k / (n + 1) (<= alpha; smaller when (n + 1) alpha is
    /// not an integer).
    pub marginal_false_alarm_bound: f64,
    /// P(this threshold's own false-alarm rate <= alpha) = 1 - I_{1-alpha}(k, n + 1 - k).
    pub confidence: f64,
    /// Share of the calibration episodes whose maximum reaches the threshold.
    pub calibration_false_alarm_rate: f64,
    /// The calibration episodes' maxima (sorted), kept so that the threshold can be
    /// recomputed when episodes judged nominal join them (absent in calibrations made
    /// before they were kept).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub episode_maxima: Vec<f64>,
}

/// The split-conformal rank k = ceil((n + 1)(1 - alpha)), 1-based; may exceed n.
///
/// The product is computed in floating point and lowered by 4 ulps' worth before the
/// ceiling, so that budgets written in decimal (0.05, 0.1) give the rank exact
/// arithmetic gives (20 * (1 - 0.05) is 19.000000000000004 in f64); a product that is
/// genuinely above an integer by more than that keeps its ceiling.
pub fn conformal_rank(n: usize, alpha: f64) -> usize {
    let v = (n as f64 + 1.0) * (1.0 - alpha);
    (v - 4.0 * f64::EPSILON * v.abs()).ceil().max(0.0) as usize
}

/// The fewest calibration episodes for which `conformal_rank(n, alpha) <= n` (capped at
/// 2^53 for absurdly small budgets): the conformal threshold at `alpha` needs at least
/// this many held-out episodes. Meaningful for alpha in (0, 1).
pub fn conformal_episodes_needed(alpha: f64) -> usize {
    const CAP: usize = 1 << 53;
    let fits = |n: usize| conformal_rank(n, alpha) <= n;
    // rank(n) - n = ceil((1 - alpha) - n alpha) (up to rounding) falls with n: double
    // until it fits, then bisect.
    let mut hi = 1usize;
    while !fits(hi) && hi < CAP {
        hi *= 2;
    }
    let mut lo = hi / 2; // does not fit (or 0)
    while hi - lo > 1 {
        let mid = lo + (hi - lo) / 2;
        if fits(mid) {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    hi
}

/// Split-conformal threshold on the fused score from the per-episode maxima of held-out
/// nominal episodes, for a per-episode false-alarm budget `alpha` (see the module doc).
///
/// Errors: alpha outside (0, 1); a non-finite episode maximum; too few episodes
/// (k > n), with the number needed for this alpha.
pub fn conformal_threshold(
    episode_max_scores: &[f64],
    alpha: f64,
) -> Result<ConformalThreshold, EvalError> {
    if !(alpha > 0.0 && alpha < 1.0) {
        return Err(EvalError::InvalidAlpha { alpha });
    }
    if let Some((index, &value)) = episode_max_scores
        .iter()
        .enumerate()
        .find(|(_, v)| !v.is_finite())
    {
        return Err(EvalError::NonFiniteScore { index, value });
    }
    let n = episode_max_scores.len();
    let rank_k = conformal_rank(n, alpha);
    if rank_k > n || rank_k == 0 {
        return Err(EvalError::TooFewEpisodes {
            n,
            alpha,
            rank_k,
            needed: conformal_episodes_needed(alpha),
        });
    }
    let mut sorted = episode_max_scores.to_vec();
    sorted.sort_by(f64::total_cmp);
    let order_statistic = sorted[rank_k - 1];
    let threshold = order_statistic.next_up();
    let alarms = sorted.iter().filter(|&&s| s >= threshold).count();
    let confidence = 1.0 - regularized_beta(rank_k as f64, (n + 1 - rank_k) as f64, 1.0 - alpha);
    Ok(ConformalThreshold {
        threshold,
        order_statistic,
        alpha,
        n,
        rank_k,
        guaranteed_false_alarm_max: alpha,
        marginal_false_alarm_bound: 1.0 - rank_k as f64 / (n as f64 + 1.0),
        confidence,
        calibration_false_alarm_rate: alarms as f64 / n as f64,
        episode_maxima: sorted,
    })
}

/// The regularised incomplete beta function I_x(a, b) = B(x; a, b) / B(a, b) (SciPy's
/// `betainc(a, b, x)`; statrs' continued fraction). NaN for a <= 0, b <= 0, x outside
/// [0, 1], infinite or NaN arguments (statrs returns an error there, or panics in its
/// unchecked form).
pub fn regularized_beta(a: f64, b: f64, x: f64) -> f64 {
    if !(a > 0.0 && b > 0.0 && (0.0..=1.0).contains(&x)) || a.is_infinite() || b.is_infinite() {
        return f64::NAN;
    }
    statrs::function::beta::checked_beta_reg(a, b, x).map_or(f64::NAN, |v| v.clamp(0.0, 1.0))
}

#[cfg(test)]
mod tests {
    use super::*;
    use statrs::function::gamma::ln_gamma;

    #[test]
    fn max_threshold_ignores_nan_and_refuses_empty() {
        assert_eq!(max_threshold(&[0.5, f64::NAN, 2.0, -1.0]), Some(2.0));
        assert_eq!(max_threshold(&[]), None);
        assert_eq!(max_threshold(&[f64::NAN]), None);
    }

    #[test]
    fn ranks_match_exact_arithmetic() {
        // (n + 1)(1 - alpha) by hand: 20 * 0.95 = 19; 20 * 0.9 = 18; 11 * 0.9 = 9.9 -> 10.
        assert_eq!(conformal_rank(19, 0.05), 19);
        assert_eq!(conformal_rank(19, 0.1), 18);
        assert_eq!(conformal_rank(10, 0.1), 10);
        assert_eq!(conformal_rank(9, 0.1), 9);
        assert_eq!(conformal_rank(48, 0.2), 40); // 49 * 0.8 = 39.2
        assert_eq!(conformal_episodes_needed(0.05), 19);
        assert_eq!(conformal_episodes_needed(0.1), 9);
        assert_eq!(conformal_episodes_needed(0.2), 4);
        assert_eq!(conformal_episodes_needed(0.3), 3); // 3 * 0.7 = 2.1 -> 3 > 2; 4 * 0.7 = 2.8 -> 3
        assert_eq!(conformal_episodes_needed(0.5), 1);
        assert_eq!(conformal_episodes_needed(0.01), 99);
        assert_eq!(conformal_episodes_needed(1e-6), 999_999);
        // (n + 1)(1 - alpha) = 1000001 * 0.999999 = 999999.999999: k = 10^6 = n.
        assert_eq!(conformal_rank(1_000_000, 1e-6), 1_000_000);
    }

    #[test]
    fn conformal_threshold_picks_the_kth_smallest() {
        // 10 episodes with maxima 1..10 (shuffled), alpha 0.2: k = ceil(11 * 0.8) = 9,
        // S_(9) = 9; only the episode with maximum 10 reaches the threshold.
        let maxima = [3.0, 10.0, 1.0, 7.0, 9.0, 2.0, 8.0, 4.0, 6.0, 5.0];
        let t = conformal_threshold(&maxima, 0.2).unwrap();
        assert_eq!(t.rank_k, 9);
        assert_eq!(t.order_statistic, 9.0);
        assert!(t.threshold > 9.0 && t.threshold < 9.000_000_001);
        assert_eq!(t.calibration_false_alarm_rate, 0.1);
        assert!((t.marginal_false_alarm_bound - 2.0 / 11.0).abs() < 1e-15);
        assert_eq!(t.guaranteed_false_alarm_max, 0.2);
        // 1 - I_0.8(9, 2) = P(Binomial(10, 0.8) <= 8) = 1 - 0.8^10 - 10 * 0.8^9 * 0.2.
        let expected = 1.0 - 0.8f64.powi(10) - 10.0 * 0.8f64.powi(9) * 0.2;
        assert!((t.confidence - expected).abs() < 1e-14, "{}", t.confidence);
    }

    #[test]
    fn ties_at_the_order_statistic_do_not_alarm() {
        let maxima = [1.0, 2.0, 2.0, 2.0, 2.0];
        // alpha 0.5: k = ceil(6 * 0.5) = 3, S_(3) = 2: the tied maxima stay below.
        let t = conformal_threshold(&maxima, 0.5).unwrap();
        assert_eq!(t.order_statistic, 2.0);
        assert_eq!(t.calibration_false_alarm_rate, 0.0);
    }

    #[test]
    fn too_few_episodes_says_how_many_are_needed() {
        let maxima = vec![1.0; 18];
        match conformal_threshold(&maxima, 0.05) {
            Err(EvalError::TooFewEpisodes {
                n, rank_k, needed, ..
            }) => {
                assert_eq!((n, rank_k, needed), (18, 19, 19));
            }
            other => panic!("{other:?}"),
        }
        assert!(conformal_threshold(&[1.0; 19], 0.05).is_ok());
        assert!(matches!(
            conformal_threshold(&[], 0.5),
            Err(EvalError::TooFewEpisodes { needed: 1, .. })
        ));
    }

    #[test]
    fn bad_inputs_are_errors() {
        for alpha in [0.0, 1.0, -0.1, f64::NAN] {
            assert!(matches!(
                conformal_threshold(&[1.0; 50], alpha),
                Err(EvalError::InvalidAlpha { .. })
            ));
        }
        assert!(matches!(
            conformal_threshold(&[1.0, f64::NAN, 2.0], 0.5),
            Err(EvalError::NonFiniteScore { index: 1, .. })
        ));
    }

    #[test]
    fn ln_gamma_at_known_values() {
        // Γ(n) = (n-1)! and Γ(1/2) = sqrt(pi). Below 15 the recurrence subtracts
        // ln(z (z+1) ... 14) (~25) from Stirling at ~15: a few ulps of 25, ~1e-14.
        assert!((ln_gamma(1.0)).abs() < 2e-14);
        assert!((ln_gamma(5.0) - 24f64.ln()).abs() < 2e-14);
        assert!((ln_gamma(0.5) - std::f64::consts::PI.sqrt().ln()).abs() < 2e-14);
        let ln_fact_20: f64 = (1..20).map(|i| (i as f64).ln()).sum();
        assert!((ln_gamma(20.0) - ln_fact_20).abs() < 1e-12);
    }

    #[test]
    fn regularized_beta_closed_forms() {
        // I_x(1, 1) = x; I_x(a, 1) = x^a; I_x(1, b) = 1 - (1-x)^b. Tolerance: ln B(a, b)
        // carries ~1e-14 absolute (see ln_gamma_at_known_values).
        for x in [0.01, 0.3, 0.5, 0.77, 0.999] {
            assert!((regularized_beta(1.0, 1.0, x) - x).abs() < 1e-13);
            assert!((regularized_beta(3.5, 1.0, x) - x.powf(3.5)).abs() < 1e-13);
            assert!((regularized_beta(1.0, 7.0, x) - (1.0 - (1.0 - x).powi(7))).abs() < 1e-13);
        }
        assert!(regularized_beta(0.0, 1.0, 0.5).is_nan());
        assert!(regularized_beta(1.0, 1.0, 1.5).is_nan());
    }
}
