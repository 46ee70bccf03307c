//! The server (`vamos serve`): gRPC streaming sessions (`vamos.v1.Monitor`), gRPC health
//! and reflection, REST administration and Prometheus metrics, in one process.
//!
//! The layers, top down (each imports only those below it):
//! - this module: [`server`] (start and shutdown, TLS, tokens, metrics, the fleet sync),
//!   [`conn`] (the connection loop: header timeouts, connection cap, graceful end),
//!   [`tls`], [`memory`] (handing unused heap back to the system);
//! - [`crate::api`]: the transports, gRPC and REST, thin handlers and one error mapping
//!   each;
//! - [`crate::session`]: sessions, the worker pool, episode scoring, profiles, jobs, in
//!   core types;
//! - the core (`pipeline`, `episode`, `robot`, `model`, `vision`, `eval`).
//!
//! [`Server::start`] binds the listeners and serves until [`RunningServer::shutdown`]
//! (or SIGTERM/SIGINT with [`serve`]): new sessions are refused, queued frames are
//! scored (up to `shutdown_grace_s`), then every stream closes with UNAVAILABLE.

pub mod conn;
pub mod memory;
pub mod server;
pub mod tls;

use crate::session::ProfileLookupError;
use crate::session::fleet::FleetError;
use crate::store::StoreError;
use std::path::PathBuf;

pub use crate::config::{FleetRole, QueuePolicy, ServiceConfig, SharedStoreConfig, TlsConfig};
pub use server::{RunningServer, Server, serve, wait_for_signal};

/// Errors of starting and stopping the server.
#[derive(Debug, thiserror::Error)]
pub enum ServiceError {
    /// An address that does not parse or bind.
    #[error("cannot listen on {addr}: {reason}")]
    Listen {
        /// The address.
        addr: String,
        /// Why.
        reason: String,
    },
    /// A refused configuration.
    #[error("invalid service settings: {0}")]
    Config(String),
    /// A profile problem.
    #[error(transparent)]
    Profile(#[from] ProfileLookupError),
    /// I/O on the data directory.
    #[error("{path}: {source}")]
    Io {
        /// The path.
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
    /// The data directory.
    #[error("data directory: {0}")]
    Store(#[from] StoreError),
    /// The shared store.
    #[error("{0}")]
    Fleet(#[from] FleetError),
    /// The gRPC transport failed.
    #[error("gRPC server: {0}")]
    Transport(String),
}
