//! vamos's server: `vamos serve`. Several robots stream to one CPU server over gRPC;
//! models, robots, profiles and thresholds are managed over REST.
//!
//! Modules, bottom up (a module imports only those before it):
//! - [`telemetry`]: `tracing` set-up (human or JSON logs, optional OTLP export).
//! - [`config`]: the settings: defaults, a TOML file, `VAMOS_*` variables; each crate's
//!   `*Config` composed, the server's own (`[service]`) and `[log]` added. The core is
//!   handed its part as `vamos_core::setup::CoreSettings`.
//! - [`store`]: the service's data directory: versioned models, robots, profiles and
//!   calibrations, written atomically with checksums, verified on open. Synchronous.
//! - [`session`]: the session layer: sessions and their lifecycle, the worker pool,
//!   episode scoring, profiles, calibration jobs, budgets and metrics, in core types
//!   (tokio, no transport crate); one error type, `SessionError`.
//! - [`api`]: the transports: gRPC (`vamos.v1.Monitor`, tonic, on the generated types of
//!   `vamos_proto`) and REST (axum), thin handlers over the session layer and the store,
//!   one error mapping each; bearer tokens.
//! - [`service`]: the server: start and shutdown, listeners, TLS, the fleet sync.

pub mod api;
pub mod config;
pub mod service;
pub mod session;
pub mod store;
pub mod telemetry;
