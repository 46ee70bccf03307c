//! vamos: Visual Anomaly MOnitoring Service.
//!
//! vamos compares the motion a robot's head camera observes with the motion it expects
//! and scores every frame for anomalies (Thoduka, Gall and Plöger, IROS 2021). This crate
//! is the library behind the `vamos` binary.
//!
//! Modules, in dependency order (a module imports only those before it):
//! - [`vision`]: images, TV-L1 optical flow, Fourier-Mellin registration, resizing and
//!   the network-input preprocessing. Synchronous, no I/O beyond image files.
//! - [`robot`]: URDF robots, kinematics, expected camera motion, rendering and the
//!   body-motion error. Synchronous.
//! - [`episode`]: recorded executions, read frame by frame (ROS 2 bags in MCAP, image
//!   folders), score bags written.
//! - [`pipeline`]: frame in, scores out: the visual front end, the per-frame [`Scorer`]
//!   fusing `e_c`, `e_b` and `e_o`, profiles and calibrations, offline episode scoring.
//!
//! [`Scorer`]: pipeline::Scorer
//! - [`model`]: the ONNX flow predictor: model bundles, ONNX Runtime sessions and the
//!   per-session prediction error `e_o`. Synchronous.
//! - [`eval`]: evaluation and calibration maths (AUC-ROC/PR as scikit-learn defines them,
//!   episode false alarms and detection delays, max and conformal thresholds, the fused
//!   score, the ablation table, PNG plots). A leaf: imports no other vamos module.
//! - [`setup`]: a profile with its robot and model loaded, making scorers.
//! - [`store`]: the service's data directory: versioned models, robots, profiles and
//!   calibrations, written atomically with checksums, verified on open. Synchronous.
//! - [`session`]: the service's session layer: sessions and their lifecycle, the worker
//!   pool, episode scoring, profiles, calibration jobs, budgets and metrics, in core
//!   types (tokio, no transport crate); one error type, `SessionError`.
//! - [`api`]: the transports: gRPC (`vamos.v1.Monitor`, tonic) and REST (axum), thin
//!   handlers over the session layer and the store, one error mapping each; the
//!   generated `vamos.v1` types and bearer tokens.
//! - [`service`]: the server: start and shutdown, listeners, TLS, the fleet sync.
//! - [`client`]: a typed gRPC client (sessions, recorded episodes replayed as live
//!   robots, batch episode scoring), used by the demo, `vamos stream` and the load
//!   generator.
//! - [`config`]: settings composed of each module's `*Config` (the server's included).
//! - [`telemetry`]: `tracing` set-up (human or JSON logs).
//! - `fuzz` (hidden): one entry point per parser of outside bytes, for the `cargo fuzz`
//!   targets in `fuzz/` and the corpus regression test; imports the modules it fuzzes.

pub use vamos_client as client;
pub use vamos_core::{episode, eval, pipeline, setup};
pub use vamos_model as model;
pub use vamos_proto as proto;
pub use vamos_robot as robot;
pub use vamos_server::{api, config, service, session, store, telemetry};
pub use vamos_vision as vision;

#[doc(hidden)]
pub mod fuzz;
