//! Score fusion: each detector at its own threshold, the window, auto / calibrated fusion,
//! broken values, and the ordering of triggered and untriggered scores.

use super::*;
use crate::eval::nominal::NominalScales;

/// Detector values from `(detector, value)` pairs.
fn values(pairs: &[(Detector, f64)]) -> DetectorValues {
    DetectorValues::of(pairs)
}

#[test]
fn each_detector_alone_at_its_own_threshold_reaches_the_alarm() {
    let scale = |location, spread| Some(Scale { location, spread });
    let t = Thresholds {
        e_c: Some(2.0),
        e_b: Some(3.0),
        scales: Some(NominalScales::from_array([
            scale(0.5, 1.0),
            scale(1.0, 2.0),
            None,
            scale(0.2, 0.1),
            scale(0.01, 0.04),
        ])),
        scene: None,
        kinematics: None,
        flow: None,
        fusion: None,
        depth: None,
    };
    // Calibrated: location + alarm * spread, the raw value without a scale.
    let d = DetectorThresholds::new(&t, 1.5, Fusion::Calibrated, false);
    let dt = |x| d.detectors[x];
    assert_eq!(
        (d.alarm, dt(Detector::Camera), dt(Detector::Body)),
        (Some(1.5), Some(2.0), Some(4.0))
    );
    assert!((dt(Detector::Scene).unwrap() - 0.35).abs() < 1e-12);
    assert_eq!(dt(Detector::Flow), Some(1.5));
    for (detector, threshold) in d.detectors.present() {
        let c = values(&[(detector, threshold)]);
        let score = fuse_frame(&c, &t, Fusion::Calibrated).score;
        assert!((score - 1.5).abs() < 1e-12, "{detector}: {score}");
    }
    assert_eq!(d.detectors.present().count(), Detector::COUNT);
    // Paper (and auto with a model): e_c/e_b at their thresholds, e_o at the alarm.
    for d in [
        DetectorThresholds::new(&t, 0.02, Fusion::Paper, false),
        DetectorThresholds::new(&t, 0.02, Fusion::Auto, true),
    ] {
        assert_eq!(
            d.detectors,
            DetectorValues::from_array([Some(2.0), Some(3.0), Some(0.02), None, None])
        );
        let c = values(&[(Detector::Flow, 0.02)]);
        assert_eq!(fuse_frame(&c, &t, Fusion::Paper).score, 0.02);
    }
    // Auto without a model is calibrated; an alarm out of reach gives no line.
    assert_eq!(
        DetectorThresholds::new(&t, 1.5, Fusion::Auto, false),
        DetectorThresholds::new(&t, 1.5, Fusion::Calibrated, false)
    );
    let high = DetectorThresholds::new(&t, TRIGGER_BASE + 1.0, Fusion::Paper, true);
    assert_eq!(
        (
            high.detectors[Detector::Flow],
            high.detectors[Detector::Camera]
        ),
        (None, Some(2.0))
    );
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
    flow: None,
    fusion: None,
    depth: None,
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
fn auto_fusion_is_calibrated_unless_fitted_for_the_paper() {
    assert_eq!(Fusion::default(), Fusion::Auto);
    let none = Thresholds::default();
    // Before a calibration, and under one that recorded its fusion: calibrated, or what
    // it was fitted for.
    for model in [false, true] {
        assert_eq!(Fusion::Auto.resolve(&none, model), Fusion::Calibrated);
        for fitted in [Fusion::Paper, Fusion::Calibrated] {
            let t = Thresholds {
                fusion: Some(fitted),
                ..T
            };
            assert_eq!(Fusion::Auto.resolve(&t, model), fitted);
        }
    }
    // A calibration made before fusions were recorded was fitted for what `auto` meant
    // then: the paper's rule with a flow predictor.
    assert_eq!(Fusion::Auto.resolve(&T, true), Fusion::Paper);
    assert_eq!(Fusion::Auto.resolve(&T, false), Fusion::Calibrated);
    assert_eq!(Fusion::Paper.resolve(&none, false), Fusion::Paper);
    assert_eq!(Fusion::Calibrated.resolve(&T, true), Fusion::Calibrated);
    // Unresolved, a frame without e_o fuses like the calibrated rule: it ranks
    // below any threshold (the paper's rule would give 0 to both).
    let th = Thresholds::paper(Some(10.0), Some(10.0));
    let low = values(&[(Detector::Camera, 1.0)]);
    let high = values(&[(Detector::Camera, 2.0)]);
    assert!(fuse_frame(&high, &th, Fusion::Auto).score > fuse_frame(&low, &th, Fusion::Auto).score);
    assert_eq!(
        fuse(low[Detector::Camera], None, None, &th).score,
        fuse(high[Detector::Camera], None, None, &th).score
    );
}

#[test]
fn calibrated_fusion_takes_the_largest_calibrated_score() {
    use crate::eval::nominal::Scale;
    let mut scales = NominalScales::default();
    scales[Detector::Camera] = Some(Scale {
        location: 1.0,
        spread: 2.0,
    });
    scales[Detector::Scene] = Some(Scale {
        location: 0.5,
        spread: 0.5,
    });
    let c = values(&[
        (Detector::Camera, 4.0),
        (Detector::Body, 0.2),
        (Detector::Scene, 2.0),
    ]);
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
        fuse(
            c[Detector::Camera],
            c[Detector::Body],
            c[Detector::Flow],
            &th
        )
    );
    let mut broken = c;
    broken[Detector::Camera] = Some(f64::NAN);
    assert_eq!(fuse_calibrated(&broken, Some(&scales)).score, RATIO_CAP);
    assert_eq!(
        fuse_calibrated(&DetectorValues::default(), None).triggered,
        None
    );
    // Below the median a score is negative and still ranks.
    let low = values(&[(Detector::Scene, 0.25)]);
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
