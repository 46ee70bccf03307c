//! The fused per-frame anomaly score (REFERENCE.md "Score"), one definition shared by
//! the pipeline, calibration and evaluation.
//!
//! The paper: score = 1 if e_c >= e_c_thres or e_b >= e_b_thres, else e_o. With e_o a
//! mean squared flow error it can exceed 1, and a triggered frame must still rank above
//! every untriggered one. The mapping here keeps two bands:
//!
//! - untriggered: score = e_o exactly (clamped at [`UNTRIGGERED_MAX`] = 5e5, far above any
//!   real e_o: network inputs are clipped to +-0.5, so realistic errors are below ~1);
//! - triggered: score = [`TRIGGER_BASE`] (1e6) + the larger ratio e / e_thres of the
//!   triggered components (capped at [`RATIO_CAP`]), so triggered frames rank above all
//!   untriggered ones and, among themselves, by how far they overshoot their threshold.
//!
//! Only the ordering matters to AUC and to thresholds on the fused score; values stay
//! finite, so they survive JSON. Plots of scores want a log axis.
//!
//! `fusion = "calibrated"` ([`Fusion::Calibrated`], [`fuse_calibrated`]): every detector's
//! value becomes its nominal-calibrated score `(e - median) / spread`
//! ([`super::nominal::Scale`], fitted on training frames: 0 at the nominal median, 1 at
//! the nominal 99th percentile) and the frame's score is the largest of them; the detector
//! that set it is `triggered`. Every detector ranks frames on its own, also below any
//! threshold, so a profile without a flow predictor still ranks every frame. Without
//! fitted scales (before calibration) a detector's raw value stands in.
//!
//! Missing components (`None`) never trigger. A NaN e_c or e_b is a failed measurement
//! and triggers with the capped ratio (a broken frame must not hide); a NaN e_o ranks at
//! the top of the untriggered band. A NaN threshold never triggers; a threshold <= 0
//! triggers with ratio 1.

use super::nominal::{CellStats, NominalScales, Scale};
use super::novelty::StateReference;
use serde::{Deserialize, Serialize};

/// Lower edge of the triggered band: every triggered score is at least this plus 1
/// (ratio >= 1), or exactly this plus 1 for thresholds <= 0.
pub const TRIGGER_BASE: f64 = 1.0e6;
/// Largest untriggered score: e_o above it is clamped (monotone, never above the band).
pub const UNTRIGGERED_MAX: f64 = 5.0e5;
/// Largest threshold overshoot ratio carried into the triggered score.
pub const RATIO_CAP: f64 = 1.0e9;

/// The per-frame detectors.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Detector {
    /// Camera-motion error e_c reached its threshold.
    Camera,
    /// Body-motion error e_b reached its threshold.
    Body,
    /// Flow-prediction error e_o (the score when no threshold was reached).
    Flow,
    /// Scene-motion residual e_r (calibrated fusion only).
    Scene,
    /// Kinematic novelty e_k (calibrated fusion only).
    Kinematics,
}

/// How the detectors' values become one score.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Fusion {
    /// `Calibrated` for a profile without a flow predictor, `Paper` with one
    /// ([`Fusion::resolve`]): without `e_o` the paper's rule ranks every untriggered frame
    /// the same, so day one (no trained model yet) gets the fusion that ranks.
    #[default]
    Auto,
    /// The paper: e_o, or the triggered band when e_c or e_b passes its training maximum.
    Paper,
    /// The largest nominal-calibrated detector score (see the module doc).
    Calibrated,
}

impl Fusion {
    /// The fusion a profile scores with, `flow_model`: whether it has a flow predictor.
    pub fn resolve(self, flow_model: bool) -> Fusion {
        match self {
            Fusion::Auto if flow_model => Fusion::Paper,
            Fusion::Auto => Fusion::Calibrated,
            other => other,
        }
    }
}

/// The detector values of one frame (`None`: not computed).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Components {
    /// Camera-motion error.
    pub e_c: Option<f64>,
    /// Body-motion error.
    pub e_b: Option<f64>,
    /// Scene-motion residual.
    pub e_r: Option<f64>,
    /// Flow-prediction error.
    pub e_o: Option<f64>,
    /// Kinematic novelty.
    pub e_k: Option<f64>,
}

/// What a scorer takes from the calibration: the paper's per-component thresholds
/// (maxima over the training episodes; `None` disables that trigger), the detectors'
/// nominal scales (calibrated fusion), the scene residual's per-cell statistics and the
/// nominal robot states of the kinematic novelty.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Thresholds {
    /// Threshold on e_c (pixels at processing resolution, as e_c itself).
    pub e_c: Option<f64>,
    /// Threshold on e_b (pixels, as e_b itself).
    pub e_b: Option<f64>,
    /// Nominal scale of each detector (calibrated fusion).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scales: Option<NominalScales>,
    /// Per-cell nominal statistics of the scene residual.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scene: Option<CellStats>,
    /// The training episodes' robot states (kinematic novelty).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub kinematics: Option<StateReference>,
}

impl Thresholds {
    /// The paper's two thresholds only.
    pub fn paper(e_c: Option<f64>, e_b: Option<f64>) -> Thresholds {
        Thresholds {
            e_c,
            e_b,
            ..Thresholds::default()
        }
    }
}

/// Each detector's own alarm threshold, in the detector's own units: the value at which
/// it alone makes a frame's fused score reach the alarm threshold `alarm` (`None`: it
/// cannot, or does not enter the fusion). For plots and the live view, which draw each
/// detector against its own line, and for the alarm records.
///
/// - paper fusion: `e_c` and `e_b` at their thresholds; `e_o` at `alarm` itself (its
///   score is `e_o`) unless `alarm` lies above [`UNTRIGGERED_MAX`] (then only `e_c`/`e_b`
///   can alarm); `e_r` does not enter;
/// - calibrated fusion: each detector where its calibrated score `(e - location) / spread`
///   reaches `alarm`, i.e. `location + alarm * spread` (its raw value when it has no
///   nominal scale), unless `alarm` lies above [`RATIO_CAP`].
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DetectorThresholds {
    /// The fused-score alarm threshold.
    pub alarm: Option<f64>,
    /// e_c, pixels.
    pub e_c: Option<f64>,
    /// e_b, pixels.
    pub e_b: Option<f64>,
    /// e_o, the flow prediction error.
    #[serde(default)]
    pub e_o: Option<f64>,
    /// e_r, the scene residual.
    #[serde(default)]
    pub e_r: Option<f64>,
    /// e_k, the kinematic novelty.
    #[serde(default)]
    pub e_k: Option<f64>,
}

impl DetectorThresholds {
    /// The thresholds of `thresholds` and `alarm` under `fusion` (resolved here with
    /// `flow_model`, as the scorer resolves it). Every value is finite or `None`.
    pub fn new(thresholds: &Thresholds, alarm: f64, fusion: Fusion, flow_model: bool) -> Self {
        let finite = |v: Option<f64>| v.filter(|x| x.is_finite());
        let alarm = finite(Some(alarm));
        match fusion.resolve(flow_model) {
            Fusion::Paper | Fusion::Auto => DetectorThresholds {
                alarm,
                e_c: finite(thresholds.e_c),
                e_b: finite(thresholds.e_b),
                e_o: alarm.filter(|a| *a <= UNTRIGGERED_MAX),
                e_r: None,
                e_k: None,
            },
            Fusion::Calibrated => {
                let scales = thresholds.scales.unwrap_or_default();
                let raw = |scale: Option<Scale>| {
                    let a = alarm.filter(|a| a.abs() <= RATIO_CAP)?;
                    finite(Some(scale.map_or(a, |s| s.location + a * s.spread)))
                };
                DetectorThresholds {
                    alarm,
                    e_c: raw(scales.e_c),
                    e_b: raw(scales.e_b),
                    e_o: raw(scales.e_o),
                    e_r: raw(scales.e_r),
                    e_k: raw(scales.e_k),
                }
            }
        }
    }
}

/// A fused score and where it came from.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Fused {
    /// The anomaly score (see the module doc for the bands).
    pub score: f64,
    /// Which detector set the score: `Camera` or `Body` when its error reached its
    /// threshold (both: the one with the larger ratio, camera on a tie), `Flow` when no
    /// threshold was reached and the score is e_o, `None` when no threshold was reached
    /// and e_o is missing (warming up; score 0).
    pub triggered: Option<Detector>,
}

impl Fused {
    /// True when a thresholded detector (camera or body) fired.
    pub fn is_triggered(&self) -> bool {
        matches!(self.triggered, Some(Detector::Camera | Detector::Body))
    }
}

/// The largest fused score of the last `n` frames (a causal windowed maximum; the
/// detector that set it comes along).
#[derive(Debug, Clone)]
pub struct Window {
    n: usize,
    recent: std::collections::VecDeque<Fused>,
}

impl Window {
    /// A window of `n` frames (at least 1).
    pub fn new(n: usize) -> Window {
        let n = n.max(1);
        Window {
            n,
            recent: std::collections::VecDeque::with_capacity(n),
        }
    }

    /// Adds a frame's fused score; returns the largest of the window (NaN is largest).
    pub fn push(&mut self, fused: Fused) -> Fused {
        if self.recent.len() == self.n {
            self.recent.pop_front();
        }
        self.recent.push_back(fused);
        let key = |f: &Fused| {
            if f.score.is_nan() {
                f64::INFINITY
            } else {
                f.score
            }
        };
        self.recent
            .iter()
            .copied()
            .reduce(|best, f| if key(&f) >= key(&best) { f } else { best })
            .unwrap_or(fused)
    }

    /// Forgets every frame.
    pub fn clear(&mut self) {
        self.recent.clear();
    }
}

/// Overshoot ratio of a component against its threshold, `None` when it does not fire.
fn overshoot(value: Option<f64>, threshold: Option<f64>) -> Option<f64> {
    let (v, t) = (value?, threshold?);
    if t.is_nan() {
        return None;
    }
    if v.is_nan() {
        return Some(RATIO_CAP);
    }
    if v < t {
        return None;
    }
    let ratio = if t > 0.0 && t.is_finite() { v / t } else { 1.0 };
    Some(ratio.min(RATIO_CAP))
}

/// The fused score of one frame under `fusion` (see the module doc; an unresolved
/// [`Fusion::Auto`] resolves on whether the frame has `e_o`: callers resolve it once per
/// profile with [`Fusion::resolve`] so that warm-up frames fuse like the rest).
pub fn fuse_frame(c: &Components, thresholds: &Thresholds, fusion: Fusion) -> Fused {
    match fusion.resolve(c.e_o.is_some()) {
        Fusion::Paper | Fusion::Auto => fuse(c.e_c, c.e_b, c.e_o, thresholds),
        Fusion::Calibrated => fuse_calibrated(c, thresholds.scales.as_ref()),
    }
}

/// The calibrated fusion: the largest nominal-calibrated detector score, clamped to
/// `+-RATIO_CAP`; NaN values (failed measurements) score `RATIO_CAP`. Score 0 and no
/// detector when no component is there.
pub fn fuse_calibrated(c: &Components, scales: Option<&NominalScales>) -> Fused {
    let s = scales.copied().unwrap_or_default();
    let parts = [
        (Detector::Camera, c.e_c, s.e_c),
        (Detector::Body, c.e_b, s.e_b),
        (Detector::Scene, c.e_r, s.e_r),
        (Detector::Flow, c.e_o, s.e_o),
        (Detector::Kinematics, c.e_k, s.e_k),
    ];
    let mut best: Option<(Detector, f64)> = None;
    for (detector, value, scale) in parts {
        let Some(v) = value else { continue };
        let z = match scale {
            Some(scale) => scale.score(v),
            None => v,
        };
        let z = if z.is_nan() {
            RATIO_CAP
        } else {
            z.clamp(-RATIO_CAP, RATIO_CAP)
        };
        if best.is_none_or(|(_, b)| z > b) {
            best = Some((detector, z));
        }
    }
    match best {
        Some((detector, score)) => Fused {
            score,
            triggered: Some(detector),
        },
        None => Fused {
            score: 0.0,
            triggered: None,
        },
    }
}

/// The paper's fusion of three errors of one frame (see the module doc).
pub fn fuse(
    e_c: Option<f64>,
    e_b: Option<f64>,
    e_o: Option<f64>,
    thresholds: &Thresholds,
) -> Fused {
    let camera = overshoot(e_c, thresholds.e_c);
    let body = overshoot(e_b, thresholds.e_b);
    let trigger = match (camera, body) {
        (Some(c), Some(b)) if b > c => Some((Detector::Body, b)),
        (Some(c), _) => Some((Detector::Camera, c)),
        (None, Some(b)) => Some((Detector::Body, b)),
        (None, None) => None,
    };
    if let Some((detector, ratio)) = trigger {
        return Fused {
            score: TRIGGER_BASE + ratio,
            triggered: Some(detector),
        };
    }
    match e_o {
        Some(v) if v.is_nan() => Fused {
            score: UNTRIGGERED_MAX,
            triggered: Some(Detector::Flow),
        },
        Some(v) => Fused {
            score: v.min(UNTRIGGERED_MAX),
            triggered: Some(Detector::Flow),
        },
        None => Fused {
            score: 0.0,
            triggered: None,
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_detector_alone_at_its_own_threshold_reaches_the_alarm() {
        let scale = |location, spread| Some(Scale { location, spread });
        let t = Thresholds {
            e_c: Some(2.0),
            e_b: Some(3.0),
            scales: Some(NominalScales {
                e_c: scale(0.5, 1.0),
                e_b: scale(1.0, 2.0),
                e_r: scale(0.2, 0.1),
                e_o: None,
                e_k: scale(0.01, 0.04),
            }),
            scene: None,
            kinematics: None,
        };
        let none = Components::default();
        // Calibrated: location + alarm * spread, the raw value without a scale.
        let d = DetectorThresholds::new(&t, 1.5, Fusion::Calibrated, false);
        assert_eq!((d.alarm, d.e_c, d.e_b), (Some(1.5), Some(2.0), Some(4.0)));
        assert!((d.e_r.unwrap() - 0.35).abs() < 1e-12 && d.e_o == Some(1.5));
        for (c, name) in [
            (Components { e_c: d.e_c, ..none }, "e_c"),
            (Components { e_b: d.e_b, ..none }, "e_b"),
            (Components { e_r: d.e_r, ..none }, "e_r"),
            (Components { e_o: d.e_o, ..none }, "e_o"),
            (Components { e_k: d.e_k, ..none }, "e_k"),
        ] {
            let score = fuse_frame(&c, &t, Fusion::Calibrated).score;
            assert!((score - 1.5).abs() < 1e-12, "{name}: {score}");
        }
        // Paper (and auto with a model): e_c/e_b at their thresholds, e_o at the alarm.
        for d in [
            DetectorThresholds::new(&t, 0.02, Fusion::Paper, false),
            DetectorThresholds::new(&t, 0.02, Fusion::Auto, true),
        ] {
            assert_eq!(
                (d.e_c, d.e_b, d.e_o, d.e_r),
                (Some(2.0), Some(3.0), Some(0.02), None)
            );
            let c = Components { e_o: d.e_o, ..none };
            assert_eq!(fuse_frame(&c, &t, Fusion::Paper).score, 0.02);
        }
        // Auto without a model is calibrated; an alarm out of reach gives no line.
        assert_eq!(
            DetectorThresholds::new(&t, 1.5, Fusion::Auto, false),
            DetectorThresholds::new(&t, 1.5, Fusion::Calibrated, false)
        );
        let high = DetectorThresholds::new(&t, TRIGGER_BASE + 1.0, Fusion::Paper, true);
        assert_eq!((high.e_o, high.e_c), (None, Some(2.0)));
        let never = DetectorThresholds::new(&t, f64::INFINITY, Fusion::Calibrated, false);
        assert_eq!(never, DetectorThresholds::default());
    }
    use proptest::prelude::*;

    const T: Thresholds = Thresholds {
        e_c: Some(2.0),
        e_b: Some(4.0),
        scales: None,
        scene: None,
        kinematics: None,
    };

    #[test]
    fn window_keeps_the_largest_recent_score() {
        let f = |score: f64, d: Detector| Fused {
            score,
            triggered: Some(d),
        };
        let mut w = Window::new(3);
        assert_eq!(w.push(f(1.0, Detector::Scene)).score, 1.0);
        assert_eq!(w.push(f(5.0, Detector::Camera)), f(5.0, Detector::Camera));
        assert_eq!(w.push(f(2.0, Detector::Scene)).score, 5.0);
        assert_eq!(w.push(f(0.5, Detector::Scene)).score, 5.0);
        // 5.0 has left the window of three.
        assert_eq!(w.push(f(0.1, Detector::Body)), f(2.0, Detector::Scene));
        assert!(w.push(f(f64::NAN, Detector::Body)).score.is_nan());
        w.clear();
        assert_eq!(w.push(f(0.3, Detector::Body)).score, 0.3);
        let mut one = Window::new(0);
        one.push(f(9.0, Detector::Body));
        assert_eq!(one.push(f(1.0, Detector::Body)).score, 1.0);
    }

    #[test]
    fn auto_fusion_is_calibrated_without_a_flow_model() {
        assert_eq!(Fusion::default(), Fusion::Auto);
        assert_eq!(Fusion::Auto.resolve(false), Fusion::Calibrated);
        assert_eq!(Fusion::Auto.resolve(true), Fusion::Paper);
        assert_eq!(Fusion::Paper.resolve(false), Fusion::Paper);
        assert_eq!(Fusion::Calibrated.resolve(true), Fusion::Calibrated);
        // Unresolved, a frame without e_o fuses like the calibrated rule: it ranks
        // below any threshold (the paper's rule would give 0 to both).
        let th = Thresholds::paper(Some(10.0), Some(10.0));
        let low = Components {
            e_c: Some(1.0),
            ..Components::default()
        };
        let high = Components {
            e_c: Some(2.0),
            ..Components::default()
        };
        assert!(
            fuse_frame(&high, &th, Fusion::Auto).score > fuse_frame(&low, &th, Fusion::Auto).score
        );
        assert_eq!(
            fuse(low.e_c, None, None, &th).score,
            fuse(high.e_c, None, None, &th).score
        );
    }

    #[test]
    fn calibrated_fusion_takes_the_largest_calibrated_score() {
        use crate::eval::nominal::Scale;
        let scales = NominalScales {
            e_c: Some(Scale {
                location: 1.0,
                spread: 2.0,
            }),
            e_b: None,
            e_r: Some(Scale {
                location: 0.5,
                spread: 0.5,
            }),
            e_o: None,
            e_k: None,
        };
        let c = Components {
            e_c: Some(4.0),
            e_b: Some(0.2),
            e_r: Some(2.0),
            e_o: None,
            e_k: None,
        };
        // e_c: 1.5; e_b: raw 0.2 (no scale); e_r: 3.0.
        let f = fuse_calibrated(&c, Some(&scales));
        assert_eq!((f.triggered, f.score), (Some(Detector::Scene), 3.0));
        let th = Thresholds {
            scales: Some(scales),
            ..T
        };
        assert_eq!(fuse_frame(&c, &th, Fusion::Calibrated), f);
        assert_eq!(
            fuse_frame(&c, &th, Fusion::Paper),
            fuse(c.e_c, c.e_b, c.e_o, &th)
        );
        let broken = Components {
            e_c: Some(f64::NAN),
            ..c
        };
        assert_eq!(fuse_calibrated(&broken, Some(&scales)).score, RATIO_CAP);
        assert_eq!(
            fuse_calibrated(&Components::default(), None).triggered,
            None
        );
        // Below the median a score is negative and still ranks.
        let low = Components {
            e_r: Some(0.25),
            ..Components::default()
        };
        assert_eq!(fuse_calibrated(&low, Some(&scales)).score, -0.5);
    }

    #[test]
    fn hand_cases() {
        // Untriggered: the score is e_o itself.
        assert_eq!(
            fuse(Some(1.0), Some(3.9), Some(0.25), &T),
            Fused {
                score: 0.25,
                triggered: Some(Detector::Flow)
            }
        );
        // e_c = 3 vs 2: ratio 1.5; e_b = 8 vs 4: ratio 2 -> body decides.
        let f = fuse(Some(3.0), Some(8.0), Some(0.1), &T);
        assert_eq!(f.triggered, Some(Detector::Body));
        assert_eq!(f.score, TRIGGER_BASE + 2.0);
        // Exactly at the threshold fires (>=), ratio 1.
        let f = fuse(Some(2.0), None, Some(7.0), &T);
        assert_eq!(
            (f.triggered, f.score),
            (Some(Detector::Camera), TRIGGER_BASE + 1.0)
        );
        // e_o > 1 untriggered still ranks below the triggered frame.
        assert!(fuse(None, None, Some(50.0), &T).score < f.score);
        // Missing components never trigger; nothing at all scores 0.
        assert_eq!(
            fuse(None, None, None, &T),
            Fused {
                score: 0.0,
                triggered: None
            }
        );
        assert!(!fuse(Some(100.0), Some(100.0), None, &Thresholds::default()).is_triggered());
    }

    #[test]
    fn broken_values_do_not_hide() {
        let f = fuse(Some(f64::NAN), Some(1.0), Some(0.1), &T);
        assert_eq!(
            (f.triggered, f.score),
            (Some(Detector::Camera), TRIGGER_BASE + RATIO_CAP)
        );
        let f = fuse(Some(0.0), Some(0.0), Some(f64::NAN), &T);
        assert_eq!(
            (f.triggered, f.score),
            (Some(Detector::Flow), UNTRIGGERED_MAX)
        );
        let nan_threshold = Thresholds::paper(Some(f64::NAN), None);
        assert!(!fuse(Some(9.0), None, Some(0.1), &nan_threshold).is_triggered());
        let zero = Thresholds::paper(Some(0.0), None);
        assert_eq!(fuse(Some(0.0), None, None, &zero).score, TRIGGER_BASE + 1.0);
    }

    fn component() -> impl Strategy<Value = Option<f64>> {
        prop_oneof![
            Just(None),
            Just(Some(f64::NAN)),
            Just(Some(f64::INFINITY)),
            Just(Some(f64::MAX)),
            (0.0..10.0f64).prop_map(Some),
            (0.0..1e12f64).prop_map(Some),
            any::<f64>().prop_map(Some),
        ]
    }

    fn thresholds() -> impl Strategy<Value = Thresholds> {
        let one = prop_oneof![Just(None), (0.0..20.0f64).prop_map(Some)];
        (one.clone(), one).prop_map(|(e_c, e_b)| Thresholds::paper(e_c, e_b))
    }

    proptest! {
        #[test]
        fn any_triggered_frame_outranks_any_untriggered_one(
            a in (component(), component(), component()),
            b in (component(), component(), component()),
            t in thresholds(),
        ) {
            let fa = fuse(a.0, a.1, a.2, &t);
            let fb = fuse(b.0, b.1, b.2, &t);
            prop_assert!(!fa.score.is_nan() && !fb.score.is_nan());
            if fa.is_triggered() && !fb.is_triggered() {
                prop_assert!(fa.score > fb.score, "{fa:?} vs {fb:?}");
            }
            if fb.is_triggered() && !fa.is_triggered() {
                prop_assert!(fb.score > fa.score, "{fa:?} vs {fb:?}");
            }
        }

        #[test]
        fn untriggered_scores_are_e_o_and_monotone(
            e_o1 in 0.0..UNTRIGGERED_MAX,
            e_o2 in 0.0..1e9f64,
            e_c in 0.0..1.9f64,
        ) {
            let f1 = fuse(Some(e_c), None, Some(e_o1), &T);
            let f2 = fuse(Some(e_c), None, Some(e_o2), &T);
            prop_assert_eq!(f1.score, e_o1);
            prop_assert_eq!(f1.score <= f2.score, e_o1 <= e_o2 || e_o2 >= UNTRIGGERED_MAX);
        }
    }
}
