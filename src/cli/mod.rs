//! Implementations of the larger CLI sub-commands (binary-only; `main.rs` dispatches).

pub mod calibrate;
pub mod demo;
pub mod episode;
pub mod eval;
pub mod export;
pub mod loadgen;
pub mod model;
pub mod progress;
pub mod render;
pub mod robot;
pub mod score;
pub mod stream;
pub mod vision_demo;
