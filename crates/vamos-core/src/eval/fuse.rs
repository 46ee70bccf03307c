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

use super::depth::LearnedDepth;
use super::detector::{Detector, DetectorValues};
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

/// How the detectors' values become one score.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum Fusion {
    /// `Calibrated`, except under a calibration that was fitted for the paper's rule
    /// ([`Fusion::resolve`]).
    #[default]
    Auto,
    /// The paper: e_o, or the triggered band when e_c or e_b passes its training maximum.
    Paper,
    /// The largest nominal-calibrated detector score (see the module doc).
    Calibrated,
}

impl Fusion {
    /// The fusion a profile scores with under `thresholds` (its calibration's), with or
    /// without a flow predictor (`flow_model`). `Paper` and `Calibrated` are themselves.
    /// `Auto` is the fusion the calibration was fitted for ([`Thresholds::fusion`]);
    /// `Calibrated` when there is no calibration. A calibration that does not say (made
    /// before 2026-12-06, when `auto` meant the paper's rule with a flow predictor) keeps
    /// the rule its alarm threshold was fitted for: `Paper` with a flow predictor.
    pub fn resolve(self, thresholds: &Thresholds, flow_model: bool) -> Fusion {
        match (self, thresholds.fusion) {
            (Fusion::Auto, Some(fitted @ (Fusion::Paper | Fusion::Calibrated))) => fitted,
            (Fusion::Auto, _) if flow_model && thresholds.is_calibrated() => Fusion::Paper,
            (Fusion::Auto, _) => Fusion::Calibrated,
            (explicit, _) => explicit,
        }
    }
}

/// What a scorer takes from the calibration: the paper's per-component thresholds
/// (maxima over the training episodes; `None` disables that trigger), the detectors'
/// nominal scales (calibrated fusion), the scene residual's per-cell statistics and the
/// nominal robot states of the kinematic novelty.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Thresholds {
    /// Threshold on e_c (pixels at processing resolution, as e_c itself).
    pub e_c: Option<f64>,
    /// Threshold on e_b (pixels, as e_b itself).
    pub e_b: Option<f64>,
    /// Nominal scale of each detector (calibrated fusion); a detector without finite
    /// nominal values has none.
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        with = "super::detector::present::option"
    )]
    #[schemars(with = "Option<NominalScales>")]
    pub scales: Option<NominalScales>,
    /// Per-cell nominal statistics of the scene residual.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schemars(with = "Option<WholeOrSummary<CellStats>>")]
    pub scene: Option<CellStats>,
    /// The training episodes' robot states (kinematic novelty).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schemars(with = "Option<WholeOrSummary<StateReference>>")]
    pub kinematics: Option<StateReference>,
    /// Per-cell nominal statistics of the flow predictor's error (`flow_pooling =
    /// "cells"`); absent: `e_o` was calibrated as the paper's mean.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schemars(with = "Option<WholeOrSummary<CellStats>>")]
    pub flow: Option<CellStats>,
    /// The fusion the calibration fitted its alarm threshold for (`paper` or
    /// `calibrated`): what `fusion = "auto"` scores with. Absent in calibrations made
    /// before 2026-12-06.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fusion: Option<Fusion>,
    /// The static scene's depth learned from the training frames
    /// (`[pipeline.camera_motion] learn_depth`): the scorer places the static scene at it
    /// wherever no depth image comes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schemars(with = "Option<WholeOrSummary<LearnedDepth>>")]
    pub depth: Option<LearnedDepth>,
}

/// The sizes of one of a calibration's bulky statistics (per-cell maps: tens of kB;
/// nominal robot states: up to about 1 MB; a learned depth's views: up to about 150 kB),
/// shown in their place where many calibrations are listed at once (the REST API's lists).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct StatsSummary {
    /// Cells across (per-cell statistics).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub columns: Option<usize>,
    /// Cells down (per-cell statistics).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rows: Option<usize>,
    /// Nominal maps the statistics come from (per-cell statistics).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub maps: Option<usize>,
    /// Phase windows (per-cell statistics per phase).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub phase_windows: Option<usize>,
    /// Values per state (nominal robot states).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dims: Option<usize>,
    /// Number of states (nominal robot states) or of views (learned depth).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub count: Option<usize>,
    /// Where the values are.
    pub detail: String,
}

impl StatsSummary {
    /// The sizes of per-cell statistics.
    pub fn of_cells(stats: &CellStats, detail: &str) -> StatsSummary {
        StatsSummary {
            columns: Some(stats.columns),
            rows: Some(stats.rows),
            maps: Some(stats.maps),
            phase_windows: stats.phases.as_ref().map(|p| p.location.len()),
            dims: None,
            count: None,
            detail: detail.into(),
        }
    }

    /// The sizes of a learned depth: its grid and number of views.
    pub fn of_depth(depth: &LearnedDepth, detail: &str) -> StatsSummary {
        StatsSummary {
            columns: Some(depth.columns),
            rows: Some(depth.rows),
            maps: None,
            phase_windows: None,
            dims: None,
            count: Some(depth.views.len()),
            detail: detail.into(),
        }
    }

    /// The sizes of nominal robot states.
    pub fn of_states(states: &StateReference, detail: &str) -> StatsSummary {
        StatsSummary {
            columns: None,
            rows: None,
            maps: None,
            phase_windows: None,
            dims: Some(states.dims()),
            count: Some(states.len()),
            detail: detail.into(),
        }
    }
}

// Never built: the schema of the JSON a bulky field holds (`#[schemars(with)]`).
/// A bulky calibration statistic: whole, or (in lists) summarised by its sizes.
#[derive(schemars::JsonSchema)]
#[serde(untagged)]
#[schemars(rename = "{T}OrSummary")]
#[allow(dead_code)]
enum WholeOrSummary<T> {
    Whole(T),
    Summary(StatsSummary),
}

impl Thresholds {
    /// Its JSON with the bulky statistics (`scene`, `flow`, `kinematics`, `depth`) replaced
    /// by their [`StatsSummary`], `detail` saying where the values are.
    pub fn summarised_json(&self, detail: &str) -> serde_json::Result<serde_json::Value> {
        let mut v = serde_json::to_value(self)?;
        let cells = [("scene", &self.scene), ("flow", &self.flow)];
        for (key, stats) in cells {
            if let Some(stats) = stats {
                v[key] = serde_json::to_value(StatsSummary::of_cells(stats, detail))?;
            }
        }
        if let Some(states) = &self.kinematics {
            v["kinematics"] = serde_json::to_value(StatsSummary::of_states(states, detail))?;
        }
        if let Some(depth) = &self.depth {
            v["depth"] = serde_json::to_value(StatsSummary::of_depth(depth, detail))?;
        }
        Ok(v)
    }
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

    /// Whether these come from a calibration (any fitted value), not the empty set a
    /// profile has before one.
    pub fn is_calibrated(&self) -> bool {
        self.e_c.is_some()
            || self.e_b.is_some()
            || self.scales.is_some()
            || self.scene.is_some()
            || self.kinematics.is_some()
            || self.flow.is_some()
            || self.fusion.is_some()
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
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize, schemars::JsonSchema)]
pub struct DetectorThresholds {
    /// The fused-score alarm threshold.
    pub alarm: Option<f64>,
    /// Each detector's threshold in its own units (`e_c`, `e_b` pixels), keyed as the
    /// values; absent in records made before a detector existed.
    #[serde(flatten)]
    pub detectors: DetectorValues,
}

impl DetectorThresholds {
    /// The thresholds of `thresholds` and `alarm` under `fusion` (resolved here with
    /// `flow_model`, as the scorer resolves it). Every value is finite or `None`.
    pub fn new(thresholds: &Thresholds, alarm: f64, fusion: Fusion, flow_model: bool) -> Self {
        let finite = |v: Option<f64>| v.filter(|x| x.is_finite());
        let alarm = finite(Some(alarm));
        match fusion.resolve(thresholds, flow_model) {
            Fusion::Paper | Fusion::Auto => DetectorThresholds {
                alarm,
                detectors: DetectorValues::from_fn(|d| match d {
                    Detector::Camera => finite(thresholds.e_c),
                    Detector::Body => finite(thresholds.e_b),
                    Detector::Flow => alarm.filter(|a| *a <= UNTRIGGERED_MAX),
                    Detector::Scene | Detector::Kinematics => None,
                }),
            },
            Fusion::Calibrated => {
                let scales = thresholds.scales.unwrap_or_default();
                let raw = |scale: Option<Scale>| {
                    let a = alarm.filter(|a| a.abs() <= RATIO_CAP)?;
                    finite(Some(scale.map_or(a, |s| s.location + a * s.spread)))
                };
                DetectorThresholds {
                    alarm,
                    detectors: scales.map(|_, scale| raw(*scale)),
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
pub fn fuse_frame(c: &DetectorValues, thresholds: &Thresholds, fusion: Fusion) -> Fused {
    match fusion.resolve(thresholds, c[Detector::Flow].is_some()) {
        Fusion::Paper | Fusion::Auto => fuse(
            c[Detector::Camera],
            c[Detector::Body],
            c[Detector::Flow],
            thresholds,
        ),
        Fusion::Calibrated => fuse_calibrated(c, thresholds.scales.as_ref()),
    }
}

/// The calibrated fusion: the largest nominal-calibrated detector score, clamped to
/// `+-RATIO_CAP`; NaN values (failed measurements) score `RATIO_CAP`. Score 0 and no
/// detector when no component is there.
pub fn fuse_calibrated(c: &DetectorValues, scales: Option<&NominalScales>) -> Fused {
    let s = scales.copied().unwrap_or_default();
    let mut best: Option<(Detector, f64)> = None;
    for (detector, value, scale) in c.zip(&s) {
        let (Some(v), scale) = (*value, *scale) else {
            continue;
        };
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
#[path = "fuse_tests.rs"]
mod tests;
