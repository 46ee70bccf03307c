//! Implementations of the larger CLI sub-commands (binary-only; `main.rs` dispatches).

pub mod calibrate;
pub mod episode;
pub mod eval;
pub mod export;
pub mod loadgen;
pub mod model;
pub mod render;
pub mod robot;
pub mod score;
