//! vamos's core: a recorded or streamed frame in, its anomaly scores out.
//!
//! Modules, in dependency order (a module imports only those before it):
//! - [`eval`]: evaluation and calibration maths (AUC-ROC/PR as scikit-learn defines them,
//!   episode false alarms and detection delays, max and conformal thresholds, the fused
//!   score, kinematic novelty, the ablation table, PNG plots). A leaf.
//! - [`episode`]: recorded executions, read frame by frame (ROS 2 bags in MCAP, image
//!   folders), score bags written.
//! - [`pipeline`]: frame in, scores out: the visual front end, the per-frame [`Scorer`]
//!   fusing the detectors, profiles and calibrations, offline episode scoring.
//! - [`setup`]: a profile with its robot and model loaded, making scorers.
//!
//! It builds on the kernel crates `vamos_vision`, `vamos_robot` and `vamos_model`, and
//! knows nothing of the server: no async runtime, no transport, no settings file.
//!
//! [`Scorer`]: pipeline::Scorer

pub mod episode;
pub mod eval;
pub mod pipeline;
pub mod setup;
