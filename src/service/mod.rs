//! The service: gRPC streaming sessions, REST administration, metrics.

pub mod proto;
