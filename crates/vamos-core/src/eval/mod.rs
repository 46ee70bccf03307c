//! Evaluation and calibration maths: frame-level ranking metrics, episode-level false
//! alarms and detection delays, threshold calibration (the paper's max-over-training and
//! split-conformal), the fused anomaly score, the ablation table and plots.
//!
//! Owns: the numeric definitions every other part of vamos shares when it talks about
//! "the score", "AUC" or "a false alarm". Pure and synchronous: no I/O except the plot
//! writers in [`plot`]. Imports no other vamos module (a leaf: the architecture test
//! checks it), so both the offline CLIs and the service can use it.
//!
//! NaN policy (one rule everywhere): a NaN score is treated as `+inf`, i.e. as an alarm
//! at every threshold. A broken frame must never hide an anomaly; it shows up as a false
//! alarm instead. Calibration refuses non-finite inputs with an error.

mod ablation;
pub mod alarm;
mod calibrate;
pub mod depth;
pub mod detector;
pub mod detector_plot;
mod episodes;
mod fuse;
mod metrics;
pub mod nominal;
pub mod novelty;
pub mod plot;

pub use ablation::{AblationTable, AucPair, FusionLevel};
pub use calibrate::{
    ConformalThreshold, conformal_episodes_needed, conformal_rank, conformal_threshold,
    max_threshold, regularized_beta,
};
pub use detector::{Detector, DetectorValues, PerDetector};
pub use episodes::{
    EpisodeOutcome, EvalReport, TypeReport, UNTYPED_ANOMALY, episode_false_alarm_rate,
    episode_outcomes, evaluate, frames_by_type, pre_onset_false_alarm_rate,
};
pub use fuse::{
    DetectorThresholds, Fused, Fusion, RATIO_CAP, StatsSummary, TRIGGER_BASE, Thresholds,
    UNTRIGGERED_MAX, Window, fuse, fuse_calibrated, fuse_frame,
};
pub use metrics::{PrPoint, RocPoint, average_precision, pr_curve, roc_auc, roc_curve};
pub use nominal::{
    CellNorm, CellStats, NominalScales, PhaseCells, Pooling, Scale, fit_scales, pool_cells,
};
pub use novelty::StateReference;

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

/// One scored frame of a labelled episode: the unit the evaluation pools over.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScoredFrame {
    /// Episode name; frames with the same name form one episode.
    pub episode: String,
    /// Image stamp in nanoseconds (ROS time).
    pub stamp_ns: i64,
    /// Fused anomaly score (higher = more anomalous; see [`fuse`]). NaN counts as `+inf`.
    pub score: f64,
    /// Ground truth: the stamp lies in a labelled anomalous interval.
    pub anomalous: bool,
    /// Anomaly type of the episode (from its labels), `None` for nominal episodes.
    pub anomaly_type: Option<String>,
    /// The predictor did not have its history yet; the score came from e_c and e_b only.
    /// Such frames are still evaluated (they carry a score).
    pub warming_up: bool,
}

/// Errors of the evaluation and calibration functions.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// The false-alarm budget must lie strictly between 0 and 1.
    #[error("false-alarm budget alpha = {alpha} must lie strictly between 0 and 1")]
    InvalidAlpha {
        /// The rejected value.
        alpha: f64,
    },
    /// Too few calibration episodes for the requested budget.
    #[error(
        "conformal calibration at alpha = {alpha} needs at least {needed} nominal \
         calibration episodes, got {n} (rank k = {rank_k} exceeds n)"
    )]
    TooFewEpisodes {
        /// Episodes given.
        n: usize,
        /// The requested budget.
        alpha: f64,
        /// The rank `ceil((n + 1)(1 - alpha))` that would be needed.
        rank_k: usize,
        /// The smallest episode count that works for this alpha.
        needed: usize,
    },
    /// A calibration value was NaN or infinite.
    #[error("calibration value #{index} is {value}; calibration needs finite scores")]
    NonFiniteScore {
        /// Position in the input slice.
        index: usize,
        /// The value.
        value: f64,
    },
    /// Two inputs that must be parallel have different lengths.
    #[error("{what}: {left} vs {right} values")]
    LengthMismatch {
        /// Which inputs.
        what: &'static str,
        /// Length of the first.
        left: usize,
        /// Length of the second.
        right: usize,
    },
    /// A plot's size is unusable.
    #[error("plot size {width_px}x{height_px} px is too small (at least 64x64)")]
    PlotSize {
        /// Requested width.
        width_px: u32,
        /// Requested height.
        height_px: u32,
    },
    /// Drawing failed inside plotters.
    #[error("drawing {path}: {message}")]
    Plot {
        /// Output file.
        path: PathBuf,
        /// plotters' message.
        message: String,
    },
    /// Writing the PNG failed.
    #[error("writing {path}: {source}")]
    Write {
        /// Output file.
        path: PathBuf,
        /// The encoder's or file system's error.
        source: image::ImageError,
    },
}
