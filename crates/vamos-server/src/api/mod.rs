//! The transports: gRPC ([`grpc`], `vamos.v1.Monitor`) and REST ([`rest`], axum). Their
//! handlers are thin: each parses its request, calls one operation of the session layer
//! ([`crate::session`]) or the data directory ([`crate::store`]), and maps the result.
//! Errors are mapped to gRPC codes in `grpc::error` and to HTTP statuses in
//! `rest::errors`, nowhere else.
//!
//! - [`proto`]: the generated `vamos.v1` types (also the client's).
//! - [`auth`]: bearer tokens and roles; [`state`]: what the handlers share.
//!
//! May import `session`, `store`, `config` and the core; the server (`crate::service`)
//! and the clients sit above it.

pub mod auth;
pub mod grpc;
pub mod observe;
pub use vamos_proto as proto;
pub mod rest;
pub mod state;

pub use state::Shared;
