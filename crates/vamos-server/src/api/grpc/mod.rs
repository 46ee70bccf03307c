//! `vamos.v1.Monitor` over gRPC (tonic): [`service`] holds the handlers, which parse,
//! call one session operation and map the result; [`convert`] turns `vamos.v1` messages
//! into the session layer's types and back; [`error`] maps errors to gRPC status codes,
//! the only place that does.

pub mod convert;
pub mod error;
pub mod service;

pub use service::MonitorService;
